"""The console's job list follows the queue's changes (``supervisor/queue``) by itself: a removed job off it, the
waiting jobs in the queue's new order; a list read before a change, come after it, does not undo it."""
from __future__ import annotations

import asyncio
import time

import pytest
from textual.widgets import DataTable

from fabric import schemas as s
from fabric.tui.app import FabricConsole
from fabric.tui.joblist import after_change, not_listed
from fabric.tui.messages import JobsListed
from fabric.tui.screens.jobs import JobsScreen

from support.tui_stub import StubClient

pytestmark = pytest.mark.timeout(60)


def rec(job_id: str, state: str) -> s.JobRecord:
    return s.JobRecord(job_id=job_id, filename=f"{job_id}.gcode", source="gcode", state=state)


# on the station, three waiting, one ended: the console's list (queue order, then the history)
JOBS = [rec("p", "printing"), rec("a", "queued"), rec("b", "planning"), rec("c", "queued"), rec("f", "finished")]


def ids(jobs: list[s.JobRecord]) -> list[str]:
    return [r.job_id for r in jobs]


def test_a_move_puts_the_waiting_jobs_in_the_queues_order_and_leaves_the_others_in_place():
    moved = after_change(JOBS, s.QueueChange(kind="moved", job_id="c", waiting=["c", "a", "b"]))
    assert ids(moved) == ["p", "c", "a", "b", "f"]
    assert moved[1] is JOBS[3]                       # the records themselves, not copies


def test_a_removal_takes_the_job_off_waiting_or_ended():
    assert ids(after_change(JOBS, s.QueueChange(kind="removed", job_id="b", waiting=["a", "c"]))) == \
        ["p", "a", "c", "f"]
    assert ids(after_change(JOBS, s.QueueChange(kind="removed", job_id="f", waiting=["a", "b", "c"]))) == \
        ["p", "a", "b", "c"]


def test_a_job_submitted_is_not_made_up_but_named_as_not_listed():
    change = s.QueueChange(kind="submitted", job_id="d", waiting=["a", "b", "c", "d"])
    assert ids(after_change(JOBS, change)) == ids(JOBS)
    assert not_listed(JOBS, change) == ["d"]
    assert not_listed(JOBS, s.QueueChange(kind="moved", job_id="a", waiting=["a", "b", "c"])) == []


async def until(pilot, predicate, timeout_s: float = 10.0, what: str = "condition") -> None:
    end = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < end, f"{what} not reached in {timeout_s:g} s"
        await pilot.pause(0.02)


def run(client: StubClient, scenario) -> None:
    async def go() -> None:
        app = FabricConsole(client)
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: ids(app.jobs) == ids(client.jobs_held), what="the first list")
            await scenario(pilot, app)
    asyncio.run(go())


def lists_shown(app: FabricConsole) -> list[list[str]]:
    """Every list the console shows from now on (its job ids)."""
    shown: list[list[str]] = []
    app.watch(app, "jobs", lambda jobs: shown.append(ids(jobs)), init=False)
    return shown


def test_a_list_read_before_a_move_does_not_undo_it():
    """Another client moved a job; a list read before (the console's own, asked for a new record) comes after the
    change: it is not shown, but read again."""
    client = StubClient(jobs=[rec("a", "queued"), rec("b", "queued")])

    async def scenario(pilot, app) -> None:
        client.jobs_held = [rec("b", "queued"), rec("a", "queued")]
        client.subscribe("supervisor", "queue").put(s.QueueChange(kind="moved", job_id="b", waiting=["b", "a"]))
        await until(pilot, lambda: ids(app.jobs) == ["b", "a"], what="the move")
        shown = lists_shown(app)
        fresh = s.JobRecord(job_id="a", filename="a.gcode", source="gcode", state="queued", stage="fresh")
        client.jobs_held = [rec("b", "queued"), fresh]
        app.post_message(JobsListed(client.keys.cell, [rec("a", "queued"), rec("b", "queued")], changes_seen=0))
        app.post_message(JobsListed(client.keys.cell, [rec("b", "queued"), fresh], changes_seen=1))  # in order: after
        await until(pilot, lambda: app.jobs[-1].stage == "fresh", what="the list read after the change")
        assert shown and all(order == ["b", "a"] for order in shown)
    run(client, scenario)


def test_a_job_removed_by_another_client_does_not_come_back():
    """Neither in a list read before its removal nor by a record of it sent before it: a job removed is gone."""
    client = StubClient(jobs=[rec("a", "queued"), rec("b", "queued")])

    async def scenario(pilot, app) -> None:
        client.jobs_held = [rec("b", "queued")]
        client.subscribe("supervisor", "queue").put(s.QueueChange(kind="removed", job_id="a", waiting=["b"]))
        await until(pilot, lambda: ids(app.jobs) == ["b"], what="the removal")
        assert any("queue: job a removed" in line for line in app.log_lines)
        shown = lists_shown(app)
        later = s.JobRecord(job_id="b", filename="b.gcode", source="gcode", state="queued", stage="later")
        client.jobs_held = [later]
        app.post_message(JobsListed(client.keys.cell, [rec("a", "queued"), rec("b", "queued")], changes_seen=0))
        records = client.subscribe("supervisor", "jobs")
        records.put(rec("a", "queued"))                   # its record, sent before the removal, come after it
        records.put(later)                                # (one stream: taken in order)
        await until(pilot, lambda: app.jobs[0].stage == "later", what="the records taken")
        assert shown and all(order == ["b"] for order in shown)
        client.jobs_held.append(rec("c", "queued"))      # another client submitted c: its change comes first
        client.subscribe("supervisor", "queue").put(s.QueueChange(kind="submitted", job_id="c", waiting=["b", "c"]))
        await until(pilot, lambda: ids(app.jobs) == ["b", "c"], what="the job submitted, read")
    run(client, scenario)


def test_the_cursor_stays_where_a_job_removed_by_another_client_was():
    """The operator's cursor on a job another client removes: it moves to the job now in that row, not to the top."""
    client = StubClient(jobs=[rec("a", "queued"), rec("b", "queued"), rec("c", "queued")])

    async def scenario(pilot, app) -> None:
        await pilot.press("2")
        await until(pilot, lambda: isinstance(app.screen, JobsScreen)
                    and app.screen.query_one("#queue", DataTable).row_count == 3, what="the Jobs screen")
        table = app.screen.query_one("#queue", DataTable)
        table.move_cursor(row=1)
        client.jobs_held = [rec("a", "queued"), rec("c", "queued")]
        client.subscribe("supervisor", "queue").put(s.QueueChange(kind="removed", job_id="b", waiting=["a", "c"]))
        await until(pilot, lambda: table.row_count == 2, what="the removal")
        assert table.coordinate_to_cell_key(table.cursor_coordinate).row_key.value == "c"
    run(client, scenario)
