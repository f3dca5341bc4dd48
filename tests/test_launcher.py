"""``fabric-cli up`` as a user runs it: five processes, a dead child reported, Ctrl-C stops them all."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
from dataclasses import replace

import pytest

from fabric.client import Client
from fabric.wire.keys import SERVICES

from support.loopback import make_settings

pytestmark = pytest.mark.timeout(180)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as fh:           # a zombie is not running
        return fh.read().split()[2] != "Z"


def test_up_starts_five_reports_a_dead_child_and_stops_all_on_ctrl_c():
    st = make_settings()
    proc = subprocess.Popen([sys.executable, "-m", "fabric.cli.main", "up", *st.to_args()],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    lines: list[str] = []
    up, seen = threading.Event(), threading.Event()

    def read() -> None:
        for line in proc.stdout:
            lines.append(line)
            if "Ctrl-C" in line:
                up.set()
            if "exited with code" in line:
                seen.set()
    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert up.wait(90), "the launcher never said the cell is up"     # printed once every child is alive
        with Client.connect(replace(st, mode="client")) as client:
            client.wait_alive(deadline_s=30)
            pids = {m.group(1): int(m.group(2)) for m in
                    (re.match(r"\s+(\w+)\s+pid (\d+)", line) for line in lines) if m}
            assert set(pids) == set(SERVICES)
            assert all(_alive(p) for p in pids.values())

            os.kill(pids["planner"], signal.SIGKILL)
            assert seen.wait(10), "the launcher did not report the dead child"
            assert any("planner exited with code -9" in line for line in lines)
            assert not client.alive(timeout=0.5)["planner"]

        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 1            # a child died: the launcher says so in its exit code
        for name, pid in pids.items():
            assert not _alive(pid), f"{name} still running after Ctrl-C"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_up_listens_where_asked_restarts_a_dead_service_and_stops_the_print_on_ctrl_c(tmp_path):
    from fabric import schemas as s
    from fabric.demo import sample_model
    from fabric.store.station import StationStore

    from support.loopback import free_port

    st = make_settings()
    port = free_port()
    listen = f"tcp/127.0.0.1:{port}"
    proc = subprocess.Popen([sys.executable, "-m", "fabric.cli.main", "up", "--cell", st.cell, "--listen", listen,
                             "--data-dir", str(tmp_path / "data")],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    lines: list[str] = []
    up, restarted = threading.Event(), threading.Event()

    def read() -> None:
        for line in proc.stdout:
            lines.append(line)
            if "Ctrl-C" in line:
                up.set()
            if "restarted" in line:
                restarted.set()
    threading.Thread(target=read, daemon=True).start()
    try:
        assert up.wait(90), "the launcher never said the cell is up: " + "".join(lines)
        client_settings = replace(st, mode="client", connect=[listen])
        with Client.connect(client_settings) as client:
            client.wait_alive(deadline_s=30)           # the children joined the hub where it listens
            pids = {m.group(1): int(m.group(2)) for m in
                    (re.match(r"\s+(\w+)\s+pid (\d+)", line) for line in lines) if m}
            os.kill(pids["station"], signal.SIGKILL)
            assert restarted.wait(30), "the launcher did not restart the station: " + "".join(lines)
            assert any("station exited with code -9; restarting" in line for line in lines)
            client.wait_alive(("station",), deadline_s=60)
            new_pid = int(re.search(r"station restarted \(pid (\d+)", "".join(lines)).group(1))

            model = sample_model().read_bytes()
            acc = client.submit(s.JobSubmit(model=model, filename="sample_part.stl", profile="robot-1.2mm",
                                            start=True, rtf=1.0))
            client.wait_print_job(acc.job_id, lambda r: r.state == "printing", timeout=120)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=60) == 1            # a child died during the run: said in the exit code
        out = "".join(lines)
        assert "stopped it at layer" in out, out
        for name, pid in {**pids, "station": new_pid}.items():
            assert not _alive(pid), f"{name} still running after Ctrl-C"
        store = StationStore(tmp_path / "data" / st.cell / "station" / "station.sqlite")
        kinds = [e.kind for e in store.events(0, 100_000)]
        assert kinds[-1] == "stopped" or "stopped" in kinds[-3:], kinds[-5:]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
