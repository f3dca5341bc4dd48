"""kill -9 of the station process mid-print: it comes back interrupted where it was, and recover finishes
the print with the bead list of an uninterrupted run."""
from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.motion.testprog import square_program
from fabric.programs import program_artifact
from fabric.robot.cell import Cell
from fabric.services.collision import CollisionService
from fabric.services.planner import PlannerService
from fabric.sim.twin import Twin
from fabric.wire.errors import StateError

pytestmark = pytest.mark.timeout(240)


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


def spawn_station(settings, data_dir: Path, log: Path) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "fabric.cli.main", "serve", "station", *settings.to_args(),
           "--data-dir", str(data_dir), "--checkpoint-s", "0.3"]
    return subprocess.Popen(cmd, stdout=open(log, "ab"), stderr=subprocess.STDOUT, start_new_session=True)


def wait_event(sub, kinds: tuple[str, ...], timeout: float = 60.0) -> s.Event:
    while True:
        ev = sub.get(timeout=timeout)
        if ev.kind in kinds:
            return ev


def test_kill_9_mid_print_then_recover(session, settings, cell, tmp_path) -> None:
    program = square_program(cell, size_mm=20, layers=4, layer_height_mm=0.5, speed_mm_s=40, nozzle_c=200.0)
    ref = Twin(cell)
    ref.load(program)
    ref.start()
    while ref.state == "printing":
        ref.advance(5.0)

    planner = PlannerService(session, settings.cell, cell)
    collision = CollisionService(session, settings.cell, cell)
    pid = planner.store_artifact(program_artifact(program))
    for svc in (planner, collision):
        svc.start()
    log = tmp_path / "station.log"
    station = spawn_station(settings, tmp_path / "data", log)
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station", "planner", "collision"), deadline_s=60)
            client.load(pid)
            events = client.subscribe("station", "events")
            try:
                client.start(rtf=50.0)                 # heat-up at 50x ...
                wait_event(events, ("layer",))
                client.set_rtf(2.0)                    # ... then mid-layer, slowly enough to be cut mid-bead
                flow = client.subscribe("station", "extrusion")
                try:
                    while not flow.get(timeout=60).on:     # the extruder's state is on the extrusion stream
                        pass
                finally:
                    flow.close()
            finally:
                events.close()
            before = client.state()
            changes = client.subscribe_alive()
            try:
                station.send_signal(signal.SIGKILL)
                station.wait(timeout=10)
                # its liveliness token goes with its link, not at once: under load the wait for the new
                # station below saw the dead one's
                while changes.get(timeout=30.0) != ("station", False):
                    pass
            finally:
                changes.close()

            station = spawn_station(settings, tmp_path / "data", log)
            client.wait_alive(("station",), deadline_s=60)
            st = client.state()
            assert st.state == "interrupted", st
            assert st.program_id == pid and st.t_sim_s >= before.t_sim_s - 0.5
            pose = client.position()
            assert not np.allclose(np.radians(pose.q_deg), cell.home_q_rad, atol=1e-3)   # not claiming home
            ready = client.ready()
            item = next(c for c in ready.checks if c.name == "robot at a known pose")
            assert not ready.ready and not item.ok and "recover" in item.detail
            kinds = [e.kind for e in client.events(0).events]
            assert kinds.count("interrupted") == 1 and "layer" in kinds                 # the log survived
            with pytest.raises(StateError):
                client.start()
            events = client.subscribe("station", "events")
            try:
                client.recover(rtf=0)
                assert wait_event(events, ("recovered", "fault")).kind == "recovered"
                assert wait_event(events, ("finished", "fault")).kind == "finished"
            finally:
                events.close()
            seqs = [e.seq for e in client.events(0).events]
            assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))                    # gap-free across the crash
            out = tmp_path / "beads.csv"
            out.write_bytes(client.mesh("csv").data)
    finally:
        station.send_signal(signal.SIGTERM)
        try:
            station.wait(timeout=30)
        except subprocess.TimeoutExpired:
            station.kill()
            station.wait()
        for svc in (collision, planner):
            svc.close()
    # the bead list as a user exports it: every bead once, as in an uninterrupted run
    header = out.read_text().splitlines()[0]
    assert header == "x0_mm,y0_mm,z0_mm,x1_mm,y1_mm,z1_mm,volume_mm3"
    got = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)
    want = ref.beads.to_arrays()
    assert len(got) == len(want["row"]) > 0
    np.testing.assert_allclose(got[:, 0:3], want["start_mm"], atol=1e-6, rtol=0)
    np.testing.assert_allclose(got[:, 3:6], want["end_mm"], atol=1e-6, rtol=0)
    np.testing.assert_allclose(got[:, 6], want["volume_mm3"], rtol=1e-9, atol=0)
