"""Services as processes: one per role and cell, a frozen station reported gone and never jumping in time."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from fabric.client import Client
from fabric.motion.testprog import square_program
from fabric.programs import program_artifact
from fabric.robot.cell import Cell
from fabric.services.collision import CollisionService
from fabric.services.planner import PlannerService

pytestmark = pytest.mark.timeout(180)


def serve(settings, name: str, data_dir, log) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "fabric.cli.main", "serve", name, *settings.to_args(),
                             "--data-dir", str(data_dir)], stdout=open(log, "ab"), stderr=subprocess.STDOUT)


def test_a_second_service_of_the_same_role_refuses_to_start(hub, settings, tmp_path):
    procs = [serve(settings, "station", tmp_path / "a", tmp_path / "first.log")]
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station",), deadline_s=60)
        procs.append(serve(settings, "station", tmp_path / "a", tmp_path / "same.log"))
        procs.append(serve(settings, "station", tmp_path / "b", tmp_path / "other.log"))
        first, same_dir, other_dir = procs
        assert same_dir.wait(timeout=60) == 2 and other_dir.wait(timeout=60) == 2
        assert "already running on this host" in (tmp_path / "same.log").read_text()
        assert f"already serving cell '{settings.cell}'" in (tmp_path / "other.log").read_text()
        assert first.poll() is None                                  # the first one keeps serving
        with Client.connect(settings) as client:
            assert client.position().seq >= 0
    finally:
        for proc in procs:                                           # none is left behind, whatever failed
            proc.terminate()
            proc.wait(timeout=20)


def test_a_frozen_station_is_gone_within_a_second_and_time_does_not_jump(hub, session, settings, tmp_path):
    cell = Cell.builtin("irb140")
    program = square_program(cell, size_mm=30, layers=6, layer_height_mm=0.5, speed_mm_s=20)
    planner = PlannerService(session, settings.cell, cell)
    collision = CollisionService(session, settings.cell, cell)
    pid = planner.store_artifact(program_artifact(program))
    for svc in (planner, collision):
        svc.start()
    station = serve(settings, "station", tmp_path / "data", tmp_path / "station.log")
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station", "planner", "collision"), deadline_s=60)
            client.load(pid)
            events = client.subscribe("station", "events")
            try:
                client.start(rtf=1.0)
                while events.get(timeout=60).kind != "layer":
                    pass
                t_before = time.monotonic()
                before = client.position().t_sim_s
                os.kill(station.pid, signal.SIGSTOP)
                t_stop = time.monotonic()
                while client.alive(timeout=0.2)["station"]:
                    assert time.monotonic() - t_stop < 1.5, "a frozen station still reported alive"
                gone_after_s = time.monotonic() - t_stop
                while time.monotonic() - t_stop < 3.0:
                    client.alive(timeout=0.2)
                os.kill(station.pid, signal.SIGCONT)
                frozen_s = time.monotonic() - t_stop
                client.wait_alive(("station",), deadline_s=30)
            finally:
                events.close()
            # events published while the link was down never reached live subscribers: the log has them all
            deadline = time.monotonic() + 30
            kinds: list[str] = []
            while "interrupted" not in kinds and time.monotonic() < deadline:
                kinds = [e.kind for e in client.events(0).events]
            st = client.state()
            after = client.position().t_sim_s
            running_s = time.monotonic() - t_before - frozen_s     # wall time the station was not frozen
            assert gone_after_s < 1.2
            assert "stall" in kinds and st.state == "interrupted" and "stalled" in st.reason
            # at rtf 1 simulated time follows the wall clock while the station runs, and holds over the freeze
            # (a jump would add the whole 3 s); the slack covers the ticks around SIGSTOP and SIGCONT
            assert after - before < running_s + 0.5, \
                f"simulated time moved {after - before:.2f} s while the station ran {running_s:.2f} s " \
                f"around a {frozen_s:.1f} s freeze"
            sub = client.subscribe("station", "events")          # before the command: at max speed it ends at once
            try:
                client.recover(rtf=0)
                while sub.get(timeout=60).kind not in ("finished", "fault"):
                    pass
            finally:
                sub.close()
            assert client.state().state == "idle"
            csv = client.mesh("csv").data.decode().splitlines()
            assert len(csv) - 1 == 6 * 4                              # every bead once
            rows = np.array([[float(v) for v in line.split(",")] for line in csv[1:]])
            assert np.all(rows[:, 6] > 0)
    finally:
        station.terminate()
        station.wait(timeout=20)
        for svc in (collision, planner):
            svc.close()
