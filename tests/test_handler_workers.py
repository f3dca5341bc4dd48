"""A command served by several workers answers a quick request while a long one runs (the collision
service's live moves do not wait behind a program of a million moves); over real in-process Zenoh."""
from __future__ import annotations

import threading
import time

import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.server.service import Service
from fabric.services.collision import CollisionService

pytestmark = pytest.mark.timeout(60)


class StandInCollision(Service):
    """``check``: a program check blocks until released; a single move answers at once."""

    name = "collision"
    partial = True

    def __init__(self, session, cell: str, workers: int) -> None:
        super().__init__(session, cell)
        self.release = threading.Event()
        self.handle("check", self.on_check, workers=workers)

    def on_check(self, req: s.CollisionRequest) -> s.CollisionReport:
        if req.program_id:
            self.release.wait(20.0)
        return s.CollisionReport(collision_free=True, checked_configs=1, min_distance_mm=1.0)


def _move_answered_during_program_check(session, settings, workers: int) -> bool:
    svc = StandInCollision(session, settings.cell, workers)
    svc.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("collision",), deadline_s=10)
            long = threading.Thread(target=lambda: client.check(s.CollisionRequest(program_id="p" * 8)))
            long.start()
            time.sleep(0.3)                                   # the program check is under way
            t0 = time.monotonic()
            try:
                client.call("collision", "check", s.CollisionRequest(q_from_deg=[0.0] * 6, q_to_deg=[1.0] * 6),
                            timeout=2.0)
                answered = time.monotonic() - t0 < 2.0
            except Exception:  # noqa: BLE001 - a timeout: it waited behind the program
                answered = False
            svc.release.set()
            long.join(30)
            return answered
    finally:
        svc.close()


def test_a_live_move_is_answered_while_a_program_is_checked(session, settings):
    assert _move_answered_during_program_check(session, settings, workers=3)


def test_one_worker_would_make_it_wait(session, settings):
    """The same with one worker: the quick request waits (what the collision service did before)."""
    assert not _move_answered_during_program_check(session, settings, workers=1)


def test_the_collision_service_serves_checks_with_several_workers(session, settings):
    from fabric.robot.cell import Cell
    svc = CollisionService(session, settings.cell, Cell.builtin("irb140"))
    assert svc._handler_workers["check"] >= 2
