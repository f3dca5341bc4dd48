"""The console sees what other clients do (issue 38, point 5): a job another client removes, moves or submits, a
plate it clears and overrides it sets show on the console within a second, with no list asked for meanwhile.

Two clients of real services in this process, on loopback Zenoh: the console (Textual's Pilot) and a plain
``Client`` that makes the changes. Every wait is on a condition, with a deadline; one second from the change for
what the console must show at once."""
from __future__ import annotations

import asyncio
import threading
from collections.abc import Awaitable, Callable

import pytest
from textual.widgets import DataTable, Static

from fabric import schemas as s
from fabric.client import Client
from fabric.motion.testprog import square_program
from fabric.programs import program_artifact
from fabric.robot.cell import Cell
from fabric.services.collision import CollisionService
from fabric.services.planner import PlannerService
from fabric.services.station import StationService
from fabric.services.supervisor import SupervisorService
from fabric.tui.app import FabricConsole
from fabric.tui.screens.cell import CellScreen
from fabric.tui.screens.jobs import JobsScreen
from fabric.tui.widgets.extruder_panel import ExtruderPanel
from fabric.tui.widgets.temps_panel import TempsPanel

pytestmark = pytest.mark.timeout(180)

GCODE = b"G21\nG90\nM83\nG1 X10 Y10 Z0.3 E0.1 F1200\n"
AT_ONCE_S = 1.0            # what another client changed is on the console within this
SETTLE_S = 60.0            # the console's first picture of the cell (services, lists) within this


async def until(pilot, predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
    """Let the app run until ``predicate()`` holds; fail after ``timeout_s``."""
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout_s
    while not predicate():
        assert loop.time() < end, f"{what}: not on the console {timeout_s:g} s after"
        await pilot.pause(0.02)


def queue_rows(app: FabricConsole) -> list[str]:
    """The job ids of the Jobs screen's queue, top to bottom."""
    if not isinstance(app.screen, JobsScreen):
        return []
    table = app.screen.query_one("#queue", DataTable)
    return [str(row.key.value) for row in table.ordered_rows]


def settled(app: FabricConsole) -> bool:
    """The console's first reads are done and no job list is being read: a list read before a change, come after
    it, would show the change too, whether or not the console followed the change itself."""
    snapshot = any(t.name == "tui:snapshot" for t in threading.enumerate())
    return not snapshot and not any(w.group == "jobs" and not w.is_finished for w in app.workers)


def text_of(app: FabricConsole, selector: str) -> str:
    return str(app.screen.query_one(selector, Static).render())


def with_console(settings, scenario: Callable[[Client, object, FabricConsole], Awaitable[None]]) -> None:
    """Run ``scenario(other, pilot, app)``: a console on a client of its own, and another client."""
    async def go() -> None:
        with Client.connect(settings) as console_client, Client.connect(settings) as other:
            app = FabricConsole(console_client)
            async with app.run_test(size=(100, 30)) as pilot:
                await scenario(other, pilot, app)
    asyncio.run(go())


@pytest.fixture
def supervisor(session, settings, tmp_path):
    """A supervisor alone: the jobs it is given wait in its queue (no planner prepares them)."""
    sup = SupervisorService(session, settings.cell, data_dir=tmp_path / "supervisor")
    sup.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("supervisor",), deadline_s=20)
        yield sup
    finally:
        sup.close()


def submit(client: Client, name: str) -> str:
    return client.submit(s.JobSubmit(model=GCODE, filename=f"{name}.gcode")).job_id


def test_the_console_drops_a_job_removed_by_another_client(supervisor, settings):
    with Client.connect(settings) as other:
        a, b = submit(other, "a"), submit(other, "b")

    async def scenario(other: Client, pilot, app: FabricConsole) -> None:
        await pilot.press("2")
        await until(pilot, lambda: queue_rows(app) == [a, b] and settled(app), SETTLE_S, "the queue of two jobs")
        other.job_remove(a)
        await until(pilot, lambda: queue_rows(app) == [b] and a not in [r.job_id for r in app.jobs], AT_ONCE_S,
                    f"job {a} removed by another client")
        assert any(f"queue: job {a} removed" in line for line in app.log_lines)
        other.job_remove(b)                                      # the last one too: an empty queue
        await until(pilot, lambda: queue_rows(app) == [] and app.jobs == [], AT_ONCE_S,
                    f"job {b} removed by another client")
    with_console(settings, scenario)


def test_the_console_follows_submits_and_moves_of_another_client(supervisor, settings):
    with Client.connect(settings) as other:
        a, b = submit(other, "a"), submit(other, "b")

    async def scenario(other: Client, pilot, app: FabricConsole) -> None:
        await pilot.press("2")
        await until(pilot, lambda: queue_rows(app) == [a, b] and settled(app), SETTLE_S, "the queue of two jobs")
        other.job_move(b, 0)
        await until(pilot, lambda: queue_rows(app) == [b, a], AT_ONCE_S, f"job {b} moved first by another client")
        c = submit(other, "c")
        await until(pilot, lambda: queue_rows(app) == [b, a, c], AT_ONCE_S, f"job {c} submitted by another client")
        other.job_move(c, 0)           # at once: the list the console reads for the new job may be read before
        await until(pilot, lambda: queue_rows(app) == [c, b, a], AT_ONCE_S, f"job {c} moved first by another client")
        other.job_move(b, 2)
        await until(pilot, lambda: queue_rows(app) == [c, a, b], AT_ONCE_S, f"job {b} moved last by another client")
        assert [r.job_id for r in app.jobs] == [c, a, b]
        # what the supervisor lists says the same (the console's own list read next does not undo it)
        assert [r.job_id for r in other.jobs().jobs] == [c, a, b]
    with_console(settings, scenario)


@pytest.fixture
def printed_part(session, settings, tmp_path):
    """A station whose plate holds the part of a print finished (loaded by hand), and the services it needs."""
    cell = Cell.builtin("irb140")
    planner = PlannerService(session, settings.cell, cell)
    collision = CollisionService(session, settings.cell, cell)
    pid = planner.store_artifact(program_artifact(square_program(cell, size_mm=10, layers=2, nozzle_c=200.0)))
    station = StationService(session, settings.cell, cell, data_dir=tmp_path / "station")
    services = (planner, collision, station)
    for svc in services:
        svc.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station", "collision", "planner"), deadline_s=30)
            events = client.subscribe("station", "events")
            try:
                client.load(pid)
                client.start(rtf=0)
                while (ev := events.get(timeout=60)).kind not in ("finished", "stopped", "fault"):
                    pass
            finally:
                events.close()
            assert ev.kind == "finished" and not client.state().plate_clear
        yield station
    finally:
        for svc in reversed(services):
            svc.close()


def test_a_plate_cleared_and_overrides_set_by_another_client_show_on_the_cell_and_jobs_screens(printed_part,
                                                                                                settings):
    async def scenario(other: Client, pilot, app: FabricConsole) -> None:
        def extruder() -> str:
            return str(app.screen.query_one(ExtruderPanel).render()) if isinstance(app.screen, CellScreen) else ""

        await until(pilot, lambda: "plate holds a part" in extruder(), SETTLE_S, "the part on the plate")
        await pilot.press("2")
        await until(pilot, lambda: isinstance(app.screen, JobsScreen)
                    and "plate holds the part printed by hand" in text_of(app, "#plate"), 10.0, "the plate's line")
        other.clear_plate()
        await until(pilot, lambda: text_of(app, "#plate") == "plate clear", AT_ONCE_S,
                    "the plate cleared by another client (Jobs screen)")
        await pilot.press("1")
        await until(pilot, lambda: "plate clear" in extruder(), AT_ONCE_S,
                    "the plate cleared by another client (Cell screen)")

        def temps() -> str:
            return str(app.screen.query_one(TempsPanel).render())

        other.overrides(speed_r=1.5, flow_r=0.8, nozzle_c=180.0, bed_c=55.0)
        await until(pilot, lambda: "speed x1.50  flow x0.80" in extruder(), AT_ONCE_S,
                    "speed and flow set by another client")
        await until(pilot, lambda: "/ 180.0 C" in temps() and "/  55.0 C" in temps(), AT_ONCE_S,
                    "set points set by another client")
    with_console(settings, scenario)
