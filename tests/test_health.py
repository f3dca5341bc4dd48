"""Health: a failing clock backs off, faults the print and says why, over the fabric and in `fabric-cli status`."""
from __future__ import annotations

import errno
import itertools
import threading
import time

import pytest

from fabric.client import Client
from fabric.motion.testprog import square_program
from fabric.programs import program_artifact
from fabric.robot.cell import Cell
from fabric.server.health import Backoff
from fabric.services.collision import CollisionService
from fabric.services.planner import PlannerService
from fabric.services.station import StationService

pytestmark = pytest.mark.timeout(120)


def test_backoff_doubles_caps_and_starts_over_after_a_healthy_run(monkeypatch):
    clock = {"t": 100.0}
    monkeypatch.setattr(time, "monotonic", lambda: clock["t"])
    b = Backoff(first_s=0.1, max_s=1.0, healthy_s=30.0)
    assert [b.failed() for _ in range(6)] == [0.1, 0.2, 0.4, 0.8, 1.0, 1.0]
    assert not b.recovered()
    clock["t"] += 31.0
    assert b.recovered() and b.failed() == 0.1


def test_a_clock_that_keeps_failing_backs_off_faults_the_print_and_says_why(session, settings, monkeypatch):
    cell = Cell.builtin("irb140")
    planner = PlannerService(session, settings.cell, cell)
    collision = CollisionService(session, settings.cell, cell)
    station = StationService(session, settings.cell, cell, pose_hz=20.0)
    pid = planner.store_artifact(program_artifact(square_program(cell, size_mm=20, layers=2, nozzle_c=200.0)))
    for svc in (planner, collision, station):
        svc.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station", "collision", "planner"), deadline_s=20)
            assert client.health("station").state == "ok"
            client.load(pid)
            client.start(rtf=1.0)
            calls = []
            full = threading.Event()

            def disk_full(events, t_sim_s, at_rest=False):    # what a full disk does under the journal
                calls.append(time.monotonic())
                full.set()
                raise OSError(errno.ENOSPC, "No space left on device")

            monkeypatch.setattr(station.journal, "record_tick", disk_full)
            assert full.wait(10)
            deadline = time.monotonic() + 10
            while len(calls) < 6 and time.monotonic() < deadline:
                time.sleep(0.05)                        # polling a counter the station's thread moves
            h = client.health("station")
            assert h.state == "degraded" and "No space left on device" in h.reasons[0]
            assert h.reasons[0].startswith("clock:")
            # backing off: the pauses grow (0.05, 0.1, 0.2, 0.4, ... s), not a hot loop
            gaps = [b - a for a, b in itertools.pairwise(calls)]
            assert len(calls) < 12 and gaps[-1] > 4 * gaps[0]
            st = client.state()                         # commands are still served while the clock fails
            assert st.state == "fault" and "No space left" in st.reason
            monkeypatch.undo()                          # the disk has room again: the clock goes on
            t0 = client.state().t_sim_s
            deadline = time.monotonic() + 10
            while client.state().t_sim_s <= t0 and time.monotonic() < deadline:
                time.sleep(0.05)
            assert client.state().t_sim_s > t0
            healths = client.healths()
            assert set(healths) == {"station", "planner", "collision"}
            assert healths["planner"].state == "ok" and healths["station"].state == "degraded"
    finally:
        for svc in (station, collision, planner):
            svc.close()


def test_every_service_serves_exactly_its_endpoints(session, settings):
    """A service missing a handler of the endpoint table refuses to start (checked at start-up)."""
    cell = Cell.builtin("irb140")
    collision = CollisionService(session, settings.cell, cell)
    del collision._handlers["check"]
    with pytest.raises(TypeError, match="missing \\['check'\\]"):
        collision.start()
    collision.close()
