"""The operator console driven with Textual's Pilot against real services (the cell's processes)."""
from __future__ import annotations

import asyncio
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
from test_collision_certify import travel_through
from test_tui_collision_hit import cell_of, glyphs

from fabric import schemas as s
from fabric.cli.up import CellProcesses
from fabric.client import Client
from fabric.demo import sample_model
from fabric.tui.app import FabricConsole
from fabric.tui.screens.cells import CellsDialog
from fabric.tui.screens.confirm import ConfirmDialog
from fabric.tui.screens.report import ReportDialog
from fabric.tui.screens.submit import SubmitDialog
from fabric.tui.screens.values import ValuesDialog
from fabric.tui.widgets.toolpath_view import HIT_GLYPH, ToolpathView
from fabric.wire.keys import SERVICES

from support.loopback import make_settings

pytestmark = pytest.mark.timeout(240)


@pytest.fixture(scope="module")
def console_cell(tmp_path_factory):
    """A cell of its own (the console prints, calibrates and overrides on it) and a second cell, a lone
    station, on the same hub."""
    st = make_settings()
    logs = Path(tmp_path_factory.mktemp("tui-logs"))
    cell = CellProcesses(st, log_dir=logs, data_dir=Path(tmp_path_factory.mktemp("tui-data")))
    cell.start(deadline_s=90.0)
    other = CellProcesses(replace(cell.settings, cell=st.cell + "b"), services=("station",), host_hub=False,
                          log_dir=logs / "b", data_dir=Path(tmp_path_factory.mktemp("tui-data-b")))
    try:
        other.start(deadline_s=90.0)
        yield cell, other
    finally:
        other.stop()
        cell.stop()


async def until(pilot, predicate, timeout_s: float = 60.0, what: str = "condition") -> None:
    """Let the app run until ``predicate()`` holds (bounded)."""
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout_s
    while not predicate():
        assert loop.time() < end, f"{what} not reached in {timeout_s:g} s"
        await pilot.pause(0.05)


async def command(pilot, key: str, name: str, *then: str) -> tuple:
    """Press ``key`` (and the keys ``then`` in the dialogs it opens); return the reply to ``name``."""
    app = pilot.app
    before = app.reply
    await pilot.press(key)
    for k in then:
        await until(pilot, lambda: app.screen.is_modal, 10.0, f"a dialog after {key}")
        await pilot.press(k)
    await until(pilot, lambda: app.reply is not before and app.reply[0] == name, 60.0, f"reply to {name}")
    return app.reply


async def dialog(pilot, dialog_type, child: str, timeout_s: float = 10.0):
    """The dialog on top, once its widget ``child`` is mounted."""
    app = pilot.app
    await until(pilot, lambda: isinstance(app.screen, dialog_type) and app.screen.query(child), timeout_s,
                dialog_type.__name__)
    return app.screen


async def apply(pilot) -> None:
    """Press the dialog's Apply button (as a click does: Button.press; a simulated mouse click was lost once in
    a loaded CI run, the dialog staying open for the whole wait)."""
    from textual.widgets import Button
    pilot.app.screen.query_one("#apply", Button).press()
    await pilot.pause()


async def fill(pilot, dialog_type, values: dict[str, str]) -> None:
    await dialog(pilot, dialog_type, f"#value-{next(iter(values))}")
    for name, value in values.items():
        pilot.app.screen.query_one(f"#value-{name}").value = value


def test_every_command_from_the_console(console_cell):
    cell, _ = console_cell

    async def scenario() -> None:
        with Client.connect(replace(cell.settings, mode="client")) as client:
            app = FabricConsole(client)
            async with app.run_test(size=(80, 24)) as pilot:
                await until(pilot, lambda: all(app.alive.get(n) for n in SERVICES), what="services alive")
                await until(pilot, lambda: app.station_state is not None and app.limits is not None)
                for key, name in (("w", "position"), ("t", "time"), ("y", "ready")):
                    ok, text = (await command(pilot, key, name))[1:]
                    assert ok, text
                    await until(pilot, lambda: isinstance(app.screen, ReportDialog), 10.0, f"{name} report")
                    report = str(app.screen.query_one("#report-text").render())
                    await pilot.press("escape")
                    if name == "position":
                        assert "TCP plate" in report and "joints" in report
                    if name == "ready":      # every check with its explanation
                        assert "✔" in report or "✘" in report
                        assert ("READY" in text) and all(":" in line for line in report.splitlines()[2:]
                                                         if line.startswith("✘"))
                # nothing is loaded: clear, typed refusals, kept on the reply line
                for key, name, keys in (("p", "pause", ()), ("r", "resume", ("enter",)),
                                        ("v", "recover", ("enter",)), ("s", "start", ("enter",)),
                                        ("c", "collisions", ())):
                    ok, text = (await command(pilot, key, name, *keys))[1:]
                    assert not ok and text.startswith("["), (name, text)
                # destructive commands ask first; "no" sends nothing; one that makes no sense now is not asked
                before = app.reply
                await pilot.press("h")
                await until(pilot, lambda: isinstance(app.screen, ConfirmDialog), 10.0, "home confirmation")
                await pilot.press("n")
                await until(pilot, lambda: not app.screen.is_modal, 10.0, "dialog closed")
                await pilot.pause(0.2)
                assert app.reply is before
                ok, text = (await command(pilot, "x", "stop"))[1:]
                assert not ok and text.startswith("nothing to stop") and not app.screen.is_modal
                assert (await command(pilot, "h", "home", "y"))[1]
                ok, text = (await command(pilot, "k", "calibrate", "y"))[1:]
                assert ok and "plate corrected" in text
                await until(pilot, lambda: isinstance(app.screen, ReportDialog), 10.0, "calibration report")
                await pilot.press("escape")
                # overrides: out of bounds is refused in the dialog, in bounds reaches the station
                await pilot.press("o")
                await fill(pilot, ValuesDialog, {"speed_r": "9"})
                await apply(pilot)
                assert "not in 0.05..4" in str(app.screen.query_one("#value-error").render())
                assert isinstance(app.screen, ValuesDialog)
                app.screen.query_one("#value-speed_r").value = "1.5"
                app.screen.query_one("#value-bed_c").value = "55"
                before = app.reply
                await apply(pilot)
                await until(pilot, lambda: app.reply is not before, what="overrides reply")
                assert app.reply[:2] == ("overrides", True), app.reply
                await until(pilot, lambda: app.station_state.speed_r == 1.5, what="speed override in the state")
                await until(pilot, lambda: app.temps is not None and app.temps.bed_target_c == 55.0)
                await pilot.press("f")
                await fill(pilot, ValuesDialog, {"rtf": "50"})
                before = app.reply
                await pilot.press("enter")
                await until(pilot, lambda: app.reply is not before, what="rtf reply")
                assert app.reply[1] and "rtf 50" in app.reply[2]
                await until(pilot, lambda: app.station_state.rtf == 50.0, what="rtf in the state")
                # the last reply stays on screen until the next
                assert "rtf 50" in str(app.screen.query_one("#reply").render())
                # jog by hand (j): up 10 mm, collision-checked, once the robot is still
                z0 = client.position().xyz_mm[2]
                ok, text = False, ""
                for _ in range(50):                       # the calibration's moves may still be ending
                    await pilot.press("j")
                    await fill(pilot, ValuesDialog, {"dz_mm": "10"})
                    before = app.reply
                    await pilot.press("enter")
                    await until(pilot, lambda b=before: app.reply is not b, what="jog reply")
                    ok, text = app.reply[1:]
                    if ok or "moving" not in text:
                        break
                    await pilot.pause(0.2)
                assert ok and "jogging by (0, 0, 10) mm" in text, text
                await until(pilot, lambda: abs(client.position().xyz_mm[2] - z0 - 10.0) < 1e-6, what="jogged up")
                # extrude by hand (E): the filament length is required; the station decides (a cold nozzle:
                # refused with why, when the material needs heat)
                await pilot.press("E")
                await fill(pilot, ValuesDialog, {"length_mm": "5"})
                before = app.reply
                await pilot.press("enter")
                await until(pilot, lambda: app.reply is not before, what="extrude reply")
                assert app.reply[0] == "extrude"
                assert app.reply[1] or "minimum extrusion temperature" in app.reply[2], app.reply
    asyncio.run(scenario())


def test_stl_to_finished_print_with_a_pause_an_override_and_the_history(console_cell, tmp_path):
    """The issue's operator: submit an STL from the file picker, pause, override, resume, read the
    history and the events, without leaving the console. A recording of the print is plotted."""
    cell, _ = console_cell
    record = tmp_path / "print.parquet"
    rec = subprocess.Popen([sys.executable, "-m", "fabric.cli.main", "record", "pose", "extrusion", "temps", "state",
                            "events", "-o", str(record), "--until-end", "--json", *cell.settings.to_args()],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert "recording" in rec.stderr.readline()          # subscribed: the print can start

    async def scenario() -> None:
        with Client.connect(replace(cell.settings, mode="client")) as client:
            app = FabricConsole(client, files_root=sample_model().parent)
            async with app.run_test(size=(160, 48)) as pilot:
                await until(pilot, lambda: app.alive.get("slicer") and app.station_state is not None)
                await pilot.press("2")
                await pilot.press("a")
                submit = await dialog(pilot, SubmitDialog, "#submit-profile #label", 30.0)   # selects mount last
                submit.query_one("#submit-path").value = str(sample_model())
                submit.query_one("#submit-profile").value = "robot-1.2mm"
                submit.query_one("#submit-rtf").value = "100"
                await pilot.pause()
                error = submit.query_one("#submit-error")
                assert await pilot.click("#submit")
                await until(pilot, lambda: app.reply and app.reply[0] == "submit", 60.0,
                            f"submit reply ({error.render()})")
                assert app.reply[1], app.reply
                await until(pilot, lambda: any(j.state == "printing" for j in app.jobs), 120.0, "printing")
                await until(pilot, lambda: app.station_state.layer >= 1, 60.0, "the second layer")
                assert (await command(pilot, "p", "pause"))[1], app.reply
                await until(pilot, lambda: app.station_state.state == "paused", what="paused")
                progress = app.station_state.progress_r
                assert 0 < progress < 1
                await pilot.press("o")
                await fill(pilot, ValuesDialog, {"speed_r": "1.5"})
                await pilot.press("enter")
                await until(pilot, lambda: app.station_state.speed_r == 1.5, what="override")
                await pilot.press("r")
                await fill(pilot, ValuesDialog, {"rtf": "0"})
                await pilot.press("enter")
                await until(pilot, lambda: any(j.state == "finished" for j in app.jobs), 120.0, "finished")
                # the history: outcome, duration and material
                table = app.screen.query_one("#history")
                await until(pilot, lambda: table.row_count == 1, what="history row")
                row = [str(c) for c in table.get_row_at(0)]
                assert "finished" in row[1] and row[2] == "sample_part.stl" and "mm3" in row[4]
                table.focus()
                await pilot.press("enter")
                await until(pilot, lambda: isinstance(app.screen, ReportDialog), what="job record")
                assert "material" in str(app.screen.query_one("#report-text").render())
                await pilot.press("escape")
                # the events: by kind, then searched
                await pilot.press("3")
                await until(pilot, lambda: app.screen.query_one("#events-table").row_count > 3, what="events")
                app.screen.query_one("#events-kind").value = "paused"
                events = app.screen
                await until(pilot, lambda: events.rows and all(e.kind == "paused" for e in events.rows), what="kind")
                events.query_one("#events-kind").clear()
                await until(pilot, lambda: len({e.kind for e in events.rows}) > 2, what="every kind again")
                events.query_one("#events-search").value = "speed_r"
                shown = events.query_one("#events-table")
                await until(pilot, lambda: 0 < shown.row_count < len(events.rows), what="search")
                assert {shown.get_row_at(i)[2] for i in range(shown.row_count)} == {"override"}
    try:
        asyncio.run(scenario())
    except BaseException:
        rec.kill()                       # the print did not end: the recorder would wait for it forever
        rec.communicate(timeout=20)
        raise
    out, err = rec.communicate(timeout=60)
    assert rec.returncode == 0, err
    assert '"end":"finished"' in out
    from fabric.cli.record_cmds import read_table
    cols = read_table(record)
    for topic in ("pose", "extrusion", "temps", "state", "events"):
        assert (cols["topic"] == topic).sum() > 0, topic
    pose_seq = cols["seq"][cols["topic"] == "pose"]
    assert (pose_seq > 0).all() and (cols["t_sim_s"] >= 0).all()
    png = tmp_path / "print.png"
    r = subprocess.run([sys.executable, "-m", "fabric.cli.main", "plot", str(record), "-o", str(png)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_the_layer_view_marks_where_the_check_hits(console_cell):
    """Issue 18: a program whose last travel goes through a printed tower, loaded on the station (the
    supervisor would refuse it); c in the console: the hit on the reply line, and the layer view on the hit's
    layer with the hit marked where it is."""
    cell, _ = console_cell
    gcode, line = travel_through(12.0)                  # 30 layers of 0.4 mm, then the travel through, at 8 mm

    async def scenario() -> None:
        with Client.connect(replace(cell.settings, mode="client")) as client:
            station = client.state()
            if not station.plate_clear:                 # another test's part
                client.clear_plate()
            req = s.PlanRequest(gcode=gcode.encode(), filename="through.gcode", wobj_xyz_mm=station.wobj_xyz_mm,
                                wobj_rpy_deg=station.wobj_rpy_deg)     # the plate as calibrated (if it was)
            pid = client.wait_job("planner", client.plan(req).job_id, timeout=120).result_id
            client.load(pid)
            app = FabricConsole(client)
            async with app.run_test(size=(120, 40)) as pilot:
                view = app.screen.query_one(ToolpathView)
                await until(pilot, lambda: view.toolpath is not None and app.station_state is not None
                            and app.station_state.program_id == pid, 60.0, "the program's toolpath")
                assert view.border_title == "layer 1/30" and HIT_GLYPH not in glyphs(view)
                ok, text = (await command(pilot, "c", "collisions"))[1:]
                assert ok and text.startswith(f"COLLISION at G-code line {line} (travel, layer 30): tool_"), text
                await until(pilot, lambda: isinstance(app.screen, ReportDialog), 10.0, "collision report")
                await pilot.press("escape")
                await until(pilot, lambda: view.border_title == f"layer 30/30 · hit line {line}", 10.0,
                            "the hit's layer")
                hit = view.hit
                assert hit.layer == 29 and hit.gcode_line == line and hit.kind == "travel"
                assert glyphs(view)[HIT_GLYPH] == [cell_of(view, hit.xyz_mm[:2])]
    asyncio.run(scenario())


def test_switching_cells(console_cell):
    cell, other = console_cell

    async def scenario() -> None:
        with Client.connect(replace(cell.settings, mode="client")) as client:
            app = FabricConsole(client)
            async with app.run_test(size=(80, 24)) as pilot:
                await until(pilot, lambda: app.alive.get("supervisor") is True, what="first cell")
                await pilot.press("g")
                options = (await dialog(pilot, CellsDialog, "#cells-list")).query_one("#cells-list")
                ids = [options.get_option_at_index(i).id for i in range(options.option_count)]
                assert cell.settings.cell in ids and other.settings.cell in ids
                options.focus()
                options.highlighted = ids.index(other.settings.cell)
                await pilot.press("enter")
                await until(pilot, lambda: app.cell == other.settings.cell, what="switched")
                await until(pilot, lambda: app.alive.get("station") is True and app.station_state is not None)
                assert app.alive.get("supervisor") is False and app.jobs == []
                assert other.settings.cell in app.sub_title
    asyncio.run(scenario())


def test_console_follows_services_coming_and_going(hub, session, settings):
    """Liveliness changes reach the console through the client's subscription (no polling)."""
    from fabric.wire.keys import Keys

    async def scenario() -> None:
        with Client.connect(replace(settings, mode="client")) as client:
            app = FabricConsole(client)
            async with app.run_test(size=(80, 24)) as pilot:
                await until(pilot, lambda: app.alive.get("planner") is False)     # the first query: nobody
                token = session.liveliness().declare_token(Keys(settings.cell).alive("planner"))
                await until(pilot, lambda: app.alive.get("planner") is True)
                token.undeclare()
                await until(pilot, lambda: app.alive.get("planner") is False)
    asyncio.run(scenario())


def test_console_without_a_hub_says_so_in_one_line():
    r = subprocess.run([sys.executable, "-m", "fabric.tui", "--connect", "tcp/127.0.0.1:1"], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [r.stderr.strip()] and "cannot reach the fabric hub" in r.stderr
    assert "Traceback" not in r.stderr


def test_the_files_screen_prints_a_library_file_again(console_cell):
    """Issue 24's file library in the console: 5 lists every submitted file with its last job; R asks, then
    queues it again with that job's settings; del asks, then forgets it (its jobs stay)."""
    from fabric.tui.screens.files import FilesScreen
    cell, _ = console_cell
    gcode = b"; filament_diameter = 1.75\nG21\nG90\nM83\nG1 Z0.4 F600\nG1 X100 Y100 F3000\nG1 X120 Y100 E1.0 F900\n"

    async def scenario() -> None:
        with Client.connect(replace(cell.settings, mode="client")) as client:
            entry = client.file_add(gcode, "library-test.gcode")
            jobs_before = client.jobs().total
            app = FabricConsole(client)
            async with app.run_test(size=(80, 24)) as pilot:
                await pilot.press("5")
                await until(pilot, lambda: isinstance(app.screen, FilesScreen), 10.0, "the files screen")
                table = app.screen.query_one("#files")
                await until(pilot, lambda: entry.file_id in table.rows, 30.0, "the file listed")
                table.focus()
                table.move_cursor(row=table.get_row_index(entry.file_id))
                await pilot.press("R")
                await dialog(pilot, ConfirmDialog, "#yes")
                await pilot.press("y")
                await until(pilot, lambda: app.reply[0] == "print again", 30.0, "the reprint's reply")
                assert app.reply[1], app.reply
                await until(pilot, lambda: client.file(entry.file_id).jobs == 1, 30.0, "the job counted")
                rec = client.job(client.file(entry.file_id).last_job_id)
                assert (rec.filename, rec.start) == ("library-test.gcode", True)
                assert client.jobs().total == jobs_before + 1
                await until(pilot, lambda: entry.file_id in table.rows, 30.0, "the list read again")
                table.move_cursor(row=table.get_row_index(entry.file_id))
                await pilot.press("delete")
                await dialog(pilot, ConfirmDialog, "#yes")
                await pilot.press("y")
                await until(pilot, lambda: entry.file_id not in table.rows, 30.0, "the file forgotten")
                assert client.files(name_contains="library-test").total == 0
                assert client.job(rec.job_id).job_id == rec.job_id            # its job stays
            settled = client.wait_print_job(rec.job_id, lambda r: r.prepared, timeout=120)
            if settled.state not in s.ON_STATION_JOB_STATES:      # leave the shared cell's queue as it was
                client.job_remove(rec.job_id)
    asyncio.run(scenario())
