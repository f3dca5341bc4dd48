"""The console over an operator's shift (issue 24), driven with Textual's Pilot against a stand-in client: every
rough edge the issue names, and the printer-host habits it asks for (samples, last folder, preheat, log, print
again)."""
from __future__ import annotations

import asyncio
import time

import pytest

from fabric import schemas as s
from fabric.samples import SAMPLES_DIR
from fabric.tui.app import FabricConsole
from fabric.tui.format import eta_text
from fabric.tui.messages import Telemetry
from fabric.tui.screens.confirm import ConfirmDialog
from fabric.tui.screens.jobs import JobsScreen
from fabric.tui.screens.log import LogScreen
from fabric.tui.screens.preheat import PreheatDialog
from fabric.tui.screens.report import ReportDialog
from fabric.tui.screens.submit import SubmitDialog
from fabric.tui.screens.values import ValuesDialog
from fabric.tui.widgets.extruder_panel import ExtruderPanel
from fabric.tui.widgets.temps_panel import TempsPanel

from support.tui_stub import StubClient

pytestmark = [pytest.mark.timeout(60), pytest.mark.slow]     # slow: 12 s of console sessions (not the fast tier)

PRINTING = s.StationState(state="printing", program_id="p", job_id="a1b2c3d4e5f6", total_s=100.0,
                          remaining_s=50.0, layers_total=10, layer=4, progress_r=0.5, rtf=10.0, plate_clear=False,
                          plate_mm3=1200.0, plate_job_id="a1b2c3d4e5f6")


def jobs() -> list[s.JobRecord]:
    return [s.JobRecord(job_id="a1b2c3d4e5f6", filename="bracket.stl", state="printing", model_id="m1",
                        start=True, rtf=5.0),
            s.JobRecord(job_id="b2c3d4e5f6a1", filename="vase.stl", state="queued", prepared=True,
                        waiting_for="plate", start=True),
            s.JobRecord(job_id="c3d4e5f6a1b2", filename="gear.gcode", source="gcode", state="finished",
                        model_id="m3", ended_s=1000.0, started_s=900.0, rtf=0.0, filament_diameter_mm=2.85)]


async def until(pilot, predicate, timeout_s: float = 10.0, what: str = "condition") -> None:
    end = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < end, f"{what} not reached in {timeout_s:g} s"
        await pilot.pause(0.02)


def console(client: StubClient | None = None, **kw) -> FabricConsole:
    return FabricConsole(client or StubClient(jobs=jobs()), **kw)


def run(scenario, client: StubClient | None = None, size=(80, 24), toasts: bool = False, **kw) -> FabricConsole:
    app = console(client, **kw)

    async def go() -> None:
        async with app.run_test(size=size, notifications=toasts) as pilot:
            await until(pilot, lambda: app.cell != "", what="the link")
            await scenario(pilot, app)
    asyncio.run(go())
    return app


def test_a_submit_with_the_sim_speed_left_empty_is_real_time_not_a_traceback():
    client = StubClient(jobs=jobs())

    async def scenario(pilot, app) -> None:
        await pilot.press("a")                              # on the Cell screen: a works on every screen
        await until(pilot, lambda: isinstance(app.screen, SubmitDialog) and app.screen.query("#submit-rtf"))
        app.screen.query_one("#submit-path").value = str(SAMPLES_DIR / "sample_part.stl")
        assert app.screen.query_one("#submit-rtf").value == ""
        await pilot.click("#submit")
        await until(pilot, lambda: client.called("submit"), what="the submit")
        await until(pilot, lambda: app.reply is not None and app.reply[0] == "submit")
        assert app.reply[1]
    run(scenario, client)
    (req,) = client.called("submit")
    assert req.rtf == 1.0 and req.filename == "sample_part.stl"


def test_ctrl_c_quits():
    async def scenario(pilot, app) -> None:
        await pilot.press("ctrl+c")
        await until(pilot, lambda: app.return_code is not None, what="quit")
    app = run(scenario)
    assert app.return_code == 0


def test_confirmations_are_consistent():
    client = StubClient(jobs=jobs(), state=PRINTING)

    async def scenario(pilot, app) -> None:
        await until(pilot, lambda: app.station_state is not None and app.station_state.state == "printing")
        await pilot.press("h")                      # home during a print: said at once, not asked then refused
        await until(pilot, lambda: app.reply is not None and app.reply[0] == "home")
        assert not app.reply[1] and "stop the print first" in app.reply[2] and not app.screen.is_modal
        assert client.called("home") == []
        await pilot.press("x")                      # stop says what happens, and what can be done after
        await until(pilot, lambda: isinstance(app.screen, ConfirmDialog))
        question = str(app.screen.query_one(".dialog Label:last-of-type").render())
        assert "restarted at a layer" in question and "cannot be resumed" not in question
        await pilot.press("n")
        await pilot.press("2")
        await pilot.press("n")                      # the next job asks: is the plate clear?
        await until(pilot, lambda: isinstance(app.screen, ConfirmDialog))
        text = " ".join(str(w.render()) for w in app.screen.query("Label"))
        assert "plate clear" in text and "1200 mm3" in text and "b2c3d4e5f6a1" in text
        assert client.called("job_next") == []
        await pilot.press("y")
        await until(pilot, lambda: client.called("job_next"), what="job next after yes")
    run(scenario, client)


def test_a_removed_job_leaves_the_jobs_screen_at_once_and_ids_are_whole():
    client = StubClient(jobs=jobs())

    async def scenario(pilot, app) -> None:
        await pilot.press("2")
        await until(pilot, lambda: isinstance(app.screen, JobsScreen))
        queue_t = app.screen.query_one("#queue")
        await until(pilot, lambda: queue_t.row_count == 2)
        assert [str(queue_t.get_row_at(i)[0]) for i in range(2)] == ["a1b2c3d4e5f6", "b2c3d4e5f6a1"]
        queue_t.focus()
        queue_t.move_cursor(row=1)
        await pilot.press("delete")
        await until(pilot, lambda: isinstance(app.screen, ConfirmDialog))
        await pilot.press("y")
        await until(pilot, lambda: queue_t.row_count == 1, what="the row gone")    # no jobs publication needed
        assert client.called("job_remove") == ["b2c3d4e5f6a1"]
    run(scenario, client)


def test_another_cell_starts_its_own_temperature_graph():
    one, two = StubClient("cell1"), StubClient("cell2")
    temps = lambda c: s.Temps(nozzle_c=c, nozzle_target_c=c, bed_c=c, bed_target_c=c)  # noqa: E731

    async def scenario(pilot, app) -> None:
        panel = app.screen.query_one(TempsPanel)
        for k in range(5):
            app.post_message(Telemetry("cell1", "temps", temps(200.0 + k)))
            await pilot.pause(0.6)
        await until(pilot, lambda: len(panel.history) >= 2)
        app._follow(two)                                          # g, then cell2
        app.post_message(Telemetry("cell1", "temps", temps(210.0)))   # late, from the link just closed
        app.post_message(Telemetry("cell2", "temps", temps(25.0)))
        await until(pilot, lambda: len(panel.history) == 1)
        await pilot.pause(0.2)
        assert {row[1] for row in panel.history} == {25.0}        # cell1's curve is not carried over
    run(scenario, one)


def test_layout_at_80x24_names_fit_and_toasts_stay_clear_of_the_reply_line_and_buttons():
    client = StubClient(jobs=jobs(), state=PRINTING)

    async def scenario(pilot, app) -> None:
        await until(pilot, lambda: app.station_state is not None)
        panel = app.screen.query_one(ExtruderPanel)
        await pilot.pause(0.2)
        shown = str(panel.render())
        assert all(name in shown for name in ("station", "slicer", "planner", "collision", "supervisor"))
        await pilot.press("s")                                  # the start dialog's labels are whole
        await until(pilot, lambda: isinstance(app.screen, ValuesDialog) and app.screen.query(".field-label"))
        for label in app.screen.query(".field-label"):
            assert label.size.width >= len(str(label.render()).strip()) > 0
        await pilot.press("escape")
        await pilot.press("y")                                  # ready: a report dialog with a Close button
        await until(pilot, lambda: isinstance(app.screen, ReportDialog))
        app.post_message(Telemetry("cell1", "events", s.Event(seq=1, t_sim_s=1.0, kind="paused", layer=3,
                                                              data={"reason": "paused by the operator"})))
        await until(pilot, lambda: app.screen.query("Toast"))
        await pilot.pause(0.3)
        close = app.screen.query_one("#close").region
        for toast in app.screen.query("Toast"):
            assert not toast.region.overlaps(close)
        await pilot.press("escape")
        reply = app.screen.query_one("#reply").region
        await until(pilot, lambda: app.screen.query("Toast"))
        for toast in app.screen.query("Toast"):
            assert not toast.region.overlaps(reply)
    run(scenario, client, toasts=True)


def test_a_new_operator_is_told_where_to_start():
    async def scenario(pilot, app) -> None:
        await pilot.pause(0.3)
        banner = str(app.screen.query_one("#banner").render())
        progress = str(app.screen.query_one("#progress").render())
        assert "IDLE" in banner and "a submits a file" in banner
        assert "a submit" in progress
        await pilot.press("a")
        await until(pilot, lambda: isinstance(app.screen, SubmitDialog) and app.screen.query("#submit-sample"))
        tree = app.screen.query_one("#submit-tree")
        assert tree.size.height >= 7                              # it showed five rows
        app.screen.submit()                                       # nothing picked yet: told to pick a file
        error = app.screen.query_one("#submit-error")
        await until(pilot, lambda: "pick a file" in str(error.render()))
        app.screen.query_one("#submit-sample").value = str(SAMPLES_DIR / "twisted_vase.stl")
        await until(pilot, lambda: app.screen.query_one("#submit-path").value.endswith("twisted_vase.stl"))
        await until(pilot, lambda: str(error.render()) == "")    # picked: the complaint is gone
    run(scenario, StubClient())


def test_the_file_picker_remembers_the_last_folder(tmp_path):
    state = tmp_path / "console.json"
    folder = tmp_path / "parts"
    folder.mkdir()
    (folder / "cube.stl").write_bytes((SAMPLES_DIR / "sample_part.stl").read_bytes())

    async def pick(pilot, app) -> None:
        await pilot.press("a")
        await until(pilot, lambda: isinstance(app.screen, SubmitDialog) and app.screen.query("#submit-path"))
        app.screen.query_one("#submit-path").value = str(folder / "cube.stl")
        await pilot.click("#submit")
        await until(pilot, lambda: app.files_root == folder)

    run(pick, state_path=state)

    async def reopen(pilot, app) -> None:
        await pilot.press("a")
        await until(pilot, lambda: isinstance(app.screen, SubmitDialog) and app.screen.query("#submit-tree"))
        assert app.screen.query_one("#submit-tree").path == folder
    run(reopen, state_path=state)                                # a new run of the console


def test_the_temperature_graph_has_a_legend_and_a_time_axis():
    async def scenario(pilot, app) -> None:
        for k in range(6):
            app.temps = s.Temps(nozzle_c=25.0 + 30 * k, nozzle_target_c=215.0, bed_c=25.0 + 5 * k, bed_target_c=60.0)
        await pilot.pause(0.2)
        text = str(app.screen.query_one(TempsPanel).render())
        assert "━ now" in text and "┄ set" in text
        assert text.splitlines()[-1].strip().startswith("-") and text.splitlines()[-1].endswith("now")
    ticks = iter(range(0, 10_000, 20))
    run(scenario, monotonic_clock=lambda: float(next(ticks)))


def test_the_eta_is_on_the_wall_clock_whatever_the_state():
    printing = s.StationState(state="printing", total_s=1000.0, remaining_s=600.0, rtf=10.0)
    paused = s.StationState(state="paused", total_s=1000.0, remaining_s=600.0, rtf=10.0)
    assert "(in 1m00s)" in eta_text(printing, 0.0)
    assert eta_text(paused, 0.0) == "paused: 1m00s to go once resumed"      # was the simulated 10m00s
    assert eta_text(s.StationState(state="printing", total_s=1.0, remaining_s=1.0, rtf=0.0), 0.0) == "at max speed"


def test_preheat_log_and_print_again():
    client = StubClient(jobs=jobs())
    client.artifacts["m3"] = b"G1 X1\n"

    async def scenario(pilot, app) -> None:
        await pilot.press("e")
        await until(pilot, lambda: isinstance(app.screen, PreheatDialog) and app.screen.query("#preheat-list"))
        options = app.screen.query_one("#preheat-list")
        options.focus()
        options.highlighted = 1                                   # PETG
        await pilot.press("enter")
        await until(pilot, lambda: client.called("overrides"))
        assert client.called("overrides") == [{"nozzle_c": 240.0, "bed_c": 80.0}]
        await pilot.press("2")
        await until(pilot, lambda: isinstance(app.screen, JobsScreen) and app.screen.query_one("#history").row_count)
        app.screen.query_one("#history").focus()
        await pilot.press("R")                                    # print the finished job again
        await until(pilot, lambda: client.called("submit"), what="the reprint")
        (req,) = client.called("submit")
        assert (req.model, req.filename, req.source, req.filament_diameter_mm) == (b"G1 X1\n", "gear.gcode",
                                                                                   "gcode", 2.85)
        app.post_message(Telemetry("cell1", "events", s.Event(seq=7, t_sim_s=3.0, kind="layer", layer=2,
                                                              data={"z_mm": 0.9})))
        await pilot.press("4")
        await until(pilot, lambda: isinstance(app.screen, LogScreen))
        await until(pilot, lambda: any("event #7 layer" in line for line in app.log_lines))
        lines = list(app.log_lines)
        assert any("overrides:" in line for line in lines) and any("print again:" in line for line in lines)
        log = app.screen.query_one("#log")
        await until(pilot, lambda: len(log.lines) >= len(lines))
    run(scenario, client)
