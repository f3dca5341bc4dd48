"""The single writer: steps in order on one thread, errors to the caller, a step not begun in time never runs,
and a long command whose state changed meanwhile changes nothing (compare-and-set, over the fabric)."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from fabric.client import Client
from fabric.robot.cell import Cell
from fabric.server.writer import Writer
from fabric.services.collision import CollisionService
from fabric.services.station import StationService
from fabric.wire.errors import ServiceUnavailable, StateError

pytestmark = pytest.mark.timeout(120)


@pytest.fixture
def running_writer():
    w, stop = Writer("test"), threading.Event()
    t = threading.Thread(target=w.run, args=(stop, 0.05), daemon=True)
    t.start()
    yield w
    stop.set()
    t.join(5)
    w.close()


def test_steps_run_in_order_on_one_thread_and_errors_reach_the_caller(running_writer):
    w, seen, threads = running_writer, [], set()

    def step(i):
        seen.append(i)
        threads.add(threading.get_ident())
        return i * 2

    futures = [w.submit(lambda i=i: step(i)) for i in range(200)]
    assert [f.result(5) for f in futures] == [2 * i for i in range(200)]
    assert seen == list(range(200)) and len(threads) == 1 and threading.get_ident() not in threads
    with pytest.raises(KeyError):
        w.call(lambda: {}["missing"])
    assert w.call(lambda: w.call(lambda: "nested")) == "nested"      # a step may call another at once


def test_a_step_not_begun_in_time_is_dropped_and_never_runs():
    w = Writer("idle")                   # no thread runs it
    ran = []
    with pytest.raises(ServiceUnavailable, match="nothing was done"):
        w.call(lambda: ran.append(1), timeout_s=0.05)
    assert w.run_pending(0) == 0 and ran == []
    late = w.submit(lambda: ran.append(2))
    gave_up = w.submit(lambda: ran.append(3))
    assert gave_up.cancel()                         # its caller gave up: closing must not trip over it
    w.close()
    with pytest.raises(ServiceUnavailable):
        late.result(0)
    with pytest.raises(ServiceUnavailable):
        w.call(lambda: 1, timeout_s=0.05)
    assert ran == []


def test_home_refuses_when_the_station_changed_while_its_move_was_checked(session, settings, monkeypatch):
    cell = Cell.builtin("irb140")
    collision = CollisionService(session, settings.cell, cell)
    station = StationService(session, settings.cell, cell)
    for svc in (collision, station):
        svc.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station", "collision"), deadline_s=20)
            real_certify = station.certify

            def certify_while_calibrated(move):               # another operator calibrates meanwhile
                real_certify(move)
                client.calibrate()

            monkeypatch.setattr(station, "certify", certify_while_calibrated)
            q_before = client.position().q_deg
            with pytest.raises(StateError, match="changed while the move home was being checked"):
                client.home()
            monkeypatch.undo()
            assert np.allclose(client.position().q_deg, q_before)     # nothing was done
            assert client.state().reason != "homing"
            assert client.home().ok                                   # asked again, it goes
    finally:
        for svc in (station, collision):
            svc.close()
