"""The supervisor says on ``supervisor/queue`` when the queue changes (a job submitted, removed, moved), with
the waiting queue in order, so that every console follows what another client did without asking again."""
from __future__ import annotations

import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.services.supervisor import SupervisorService
from fabric.wire.errors import NotFound

pytestmark = pytest.mark.timeout(120)
GCODE = b"G21\nG90\nM83\nG1 X10 Y10 Z0.3 E0.1 F1200\n"


def _next(sub, kind: str) -> s.QueueChange:
    while True:
        change = sub.get(timeout=20.0)
        if change.kind == kind:
            return change


def test_a_submit_a_move_and_a_removal_are_published_with_the_queue_after_them(session, settings) -> None:
    sup = SupervisorService(session, settings.cell)      # alone: its jobs wait for a planner, in the queue
    sup.start()
    try:
        with Client.connect(settings) as one, Client.connect(settings) as other:
            one.wait_alive(("supervisor",), deadline_s=20)
            changes = other.subscribe("supervisor", "queue")
            try:
                a = one.submit(s.JobSubmit(model=GCODE, filename="a.gcode")).job_id
                assert _next(changes, "submitted").job_id == a
                b = one.submit(s.JobSubmit(model=GCODE, filename="b.gcode")).job_id
                assert _next(changes, "submitted").waiting == [a, b]
                one.job_move(b, 0)
                moved = _next(changes, "moved")
                assert (moved.job_id, moved.waiting) == (b, [b, a])
                one.job_remove(a)
                removed = _next(changes, "removed")
                assert (removed.job_id, removed.waiting) == (a, [b])
                with pytest.raises(NotFound):
                    other.job(a)                              # gone: the change said so first
            finally:
                changes.close()
    finally:
        sup.close()
