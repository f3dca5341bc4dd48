"""Fault injection against a real cell: kill -9 a service at a seeded random instant of a job, let the
launcher's supervision restart it, recover, and compare the job and its bead list with an undisturbed run.

Shared by the CI tier (tests/test_faults.py, one instant per service) and the long version
(tools/bench/fault_bench.py, many instants per service).
"""
from __future__ import annotations

import os
import signal
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from fabric import schemas as s
from fabric.cli.up import CellProcesses
from fabric.client import Client
from fabric.demo import sample_model
from fabric.programs import program_from_artifact
from fabric.robot.cell import Cell
from fabric.sim.twin import Twin
from fabric.wire.config import SessionSettings
from fabric.wire.errors import FabricError

PROFILE = "robot-1.2mm"
KILL_PHASE = {"slicer": "slicing", "planner": "planning", "station": "printing", "supervisor": None}
PRINT_RTF = {"station": 300.0}        # slow enough that the kill lands mid-print; the others at max speed


@dataclass
class FaultRun:
    """What one disturbed job ended as."""

    service: str
    delay_s: float
    killed_in: str
    record: s.JobRecord
    beads_csv: bytes
    program_id: str
    recovery_s: float | None = None      # kill -> printing again (station kills)
    notes: list[str] = field(default_factory=list)


class SupervisedCell:
    """A cell whose services run as processes, restarted by a background supervision loop."""

    def __init__(self, settings: SessionSettings, data_dir: Path, log_dir: Path) -> None:
        self.cell = CellProcesses(settings, log_dir=log_dir, data_dir=data_dir)
        self.settings = replace(self.cell.settings, mode="client")
        self._stop = threading.Event()
        self.log: list[str] = []

    def __enter__(self) -> SupervisedCell:
        self.cell.start(deadline_s=120.0)
        self._thread = threading.Thread(target=self._supervise, daemon=True)
        self._thread.start()
        return self

    def _supervise(self) -> None:
        while not self._stop.wait(0.05):
            self.cell.supervise(self.log.append)

    def kill(self, service: str) -> None:
        os.kill(self.cell.procs[service].pid, signal.SIGKILL)

    def kill_all(self) -> None:
        """The whole cell dies at once (power cut of the host, kill -9 of every process)."""
        self._stop.set()
        self._thread.join()
        for proc in self.cell.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGKILL)
        for proc in self.cell.procs.values():
            proc.wait()
        self.cell.stop()

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self.cell.stop()


def reference_beads(client: Client, program_id: str) -> np.ndarray:
    """The bead list of an undisturbed run of the program, as the CSV export's rows."""
    program = program_from_artifact(client.artifact("planner", program_id))
    twin = Twin(Cell.builtin("irb140"))
    twin.load(program)
    twin.start()
    while twin.state == "printing":
        twin.advance(50.0)
    b = twin.beads
    return np.column_stack([b.start_mm, b.end_mm, b.volume_mm3])


def read_csv(data: bytes) -> np.ndarray:
    lines = data.decode().splitlines()[1:]
    return np.array([[float(v) for v in line.split(",")] for line in lines]).reshape(-1, 7)


def same_beads(got: np.ndarray, want: np.ndarray) -> bool:
    """Same count, coordinates within 1e-6 mm, volumes within 1e-9 relative."""
    return (got.shape == want.shape and bool(np.all(np.abs(got[:, :6] - want[:, :6]) <= 1e-6))
            and bool(np.all(np.abs(got[:, 6] - want[:, 6]) <= 1e-9 * np.abs(want[:, 6]))))


def wait_state(client: Client, job_id: str, states: tuple[str, ...], timeout_s: float) -> s.JobRecord:
    """Poll the job's record (the supervisor may be restarting) until it is in ``states``."""
    end = time.monotonic() + timeout_s
    last = None
    while time.monotonic() < end:
        try:
            last = client.job(job_id)
            if last.state in states:
                return last
        except FabricError as exc:               # the supervisor is away (restarting): ask again
            last = exc
        time.sleep(0.05)           # a poll, bounded by the deadline: the supervisor may be restarting
    raise AssertionError(f"job {job_id} not in {states} after {timeout_s:g} s (last: {last})")


def run_with_fault(sc: SupervisedCell, service: str, delay_s: float) -> FaultRun:
    """Submit the sample part, kill ``service`` ``delay_s`` after the job enters its phase, recover,
    run to the end; returns what the job ended as."""
    model = sample_model().read_bytes()
    rtf = PRINT_RTF.get(service, 0.0)
    with Client.connect(sc.settings) as client:
        acc = client.submit(s.JobSubmit(model=model, filename="sample_part.stl", profile=PROFILE,
                                        start=True, rtf=rtf))
        phase = KILL_PHASE[service]
        if phase == "printing":                   # after the heat-up: while beads are being deposited
            wait_state(client, acc.job_id, (phase,), 120.0)
            client.wait_print_job(acc.job_id, lambda r: r.layer >= 0, timeout=300.0)
        elif phase is not None:
            wait_state(client, acc.job_id, (phase,), 120.0)
        time.sleep(delay_s)        # the injected fault's seeded instant, not a synchronisation
        t_kill = time.monotonic()
        killed_in = client.job(acc.job_id).state
        sc.kill(service)
        gone_by = time.monotonic() + 10.0
        while client.alive(timeout=0.3).get(service) and time.monotonic() < gone_by:
            pass                                       # the kill is seen on the fabric before going on
        recovery = None
        notes: list[str] = []
        rec = wait_state(client, acc.job_id, ("finished", "failed", "stopped", "interrupted"), 300.0)
        if rec.state == "interrupted":
            client.wait_alive(("station", "collision"), deadline_s=60)
            client.recover(rtf=0.0)
            recovery = time.monotonic() - t_kill
            notes.append("recovered")
            rec = wait_state(client, acc.job_id, ("finished", "failed", "stopped"), 300.0)
        client.wait_alive(deadline_s=60)               # a service killed after the print is back
        csv = client.mesh("csv").data
        return FaultRun(service, delay_s, killed_in, rec, csv, rec.program_id, recovery, notes)
