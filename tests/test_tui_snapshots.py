"""SVG snapshots of each console screen at 80x24 and 160x48, in a fixed state (no services, frozen clocks)."""
from __future__ import annotations

import itertools
import time

import pytest

from fabric import schemas as s
from fabric.motion.program import MOVEL, PRINT, Program
from fabric.samples import SAMPLES_DIR
from fabric.tui.app import FabricConsole
from fabric.tui.messages import CollisionChecked
from fabric.tui.screens.submit import SubmitDialog
from fabric.tui.toolpath import Toolpath

pytestmark = [pytest.mark.timeout(120), pytest.mark.slow]    # slow: 24 snapshots, 15 s (not the fast tier)

SIZES = {"80x24": (80, 24), "160x48": (160, 48)}
NOW_S = 1_767_225_600.0          # 2026-01-01 00:00:00 UTC


@pytest.fixture(autouse=True)
def utc(monkeypatch):
    """The ETA and job times are local times: fix the zone."""
    monkeypatch.setenv("TZ", "UTC")
    time.tzset()
    yield
    monkeypatch.undo()
    time.tzset()


def square_layers(layers: int = 4, side_mm: float = 40.0) -> Toolpath:
    """A program of square perimeters with a diagonal infill line per layer."""
    pts = []
    for k in range(layers):
        z = 0.3 * (k + 1)
        for x, y, flow in ((0, 0, 0.0), (side_mm, 0, 1), (side_mm, side_mm, 1), (0, side_mm, 1), (0, 0, 1),
                           (side_mm, side_mm, 1), (side_mm / 2, 0, 0.0), (side_mm / 2, side_mm, 1)):
            pts.append((x + 80, y + 90, z, flow, k))
    prog = Program.empty(len(pts) + 1)
    prog.op[:] = MOVEL
    prog.section[1:] = PRINT
    prog.xyz_mm[1:] = [(x, y, z) for x, y, z, _, _ in pts]
    prog.xyz_mm[0] = prog.xyz_mm[1]
    prog.flow_mm3_mm[1:] = [f for *_, f, _ in pts]
    prog.layer[1:] = [k for *_, k in pts]
    return Toolpath.from_program(prog)


def job(job_id: str, state: str, filename: str, **kw) -> s.JobRecord:
    return s.JobRecord(job_id=job_id, filename=filename, state=state, created_s=NOW_S - 3600, **kw)


PLAN = s.PlanSummary(program_id="p", targets=11898, moves=11890, layers=40, feasible_r=1.0, runnable=True,
                     estimate_s=1587.2, extruded_mm3=6108.0, path_mm=48000.0, filament_diameter_mm=2.85,
                     material_source="gcode", material="PLA")
SEGMENTS = [s.JobSegment(began="start", started_s=NOW_S - 7200, ended_s=NOW_S - 6700, ended="stopped",
                         reason="stopped by the operator", sim_s=980.0, deposited_mm3=3900.0, pauses=1, last_layer=24),
            s.JobSegment(began="restart", from_layer=24, started_s=NOW_S - 6000, ended_s=NOW_S - 5600,
                         ended="finished", sim_s=607.2, deposited_mm3=2629.0, last_layer=39)]
OVERRIDES = [s.JobOverride(wall_s=NOW_S - 7000, t_sim_s=300.0, layer=8, speed_r=1.5, flow_r=1.1)]
JOBS = [
    job("a1b2c3d4e5f6", "printing", "bracket.stl", stage="printing layer 3", started_s=NOW_S - 600),
    job("b2c3d4e5f6a1", "queued", "vase.stl", prepared=True, waiting_for="plate", stage="prepared"),
    job("c3d4e5f6a1b2", "finished", "sample_part.stl", started_s=NOW_S - 7200, ended_s=NOW_S - 5600,
        sim_elapsed_s=1587.2, wall_elapsed_s=900.0, deposited_mm3=6529.0, filament_mm=2712.0, plan=PLAN,
        segments=SEGMENTS, live_overrides=OVERRIDES, progress_r=1.0),
    job("d4e5f6a1b2c3", "stopped", "gear.3mf", started_s=NOW_S - 9000, ended_s=NOW_S - 8800,
        sim_elapsed_s=200.0, wall_elapsed_s=20.0, deposited_mm3=512.0, filament_mm=213.0,
        reason="stopped by the operator at layer 4 of 40"),
    job("e5f6a1b2c3d4", "failed", "tower.stl", ended_s=NOW_S - 9500, reason="unreachable: G-code line 1234"),
]
FILES = [
    s.LibraryFile(file_id="8c1f0a9e7b52", name="sample_part.stl", source="model", size_bytes=68484,
                  added_s=NOW_S - 86400, used_s=NOW_S - 7200, jobs=3, last_job_id="c3d4e5f6a1b2",
                  last_state="finished", layers=40, extruded_mm3=6108.0, estimate_s=1587.2),
    s.LibraryFile(file_id="0d4be97c21a5", name="bracket.gcode", source="gcode", size_bytes=1873402,
                  added_s=NOW_S - 3600, used_s=NOW_S - 600, jobs=1, last_job_id="a1b2c3d4e5f6",
                  last_state="printing", layers=58, extruded_mm3=6819.4, estimate_s=1520.4),
    s.LibraryFile(file_id="5e7a90c3d1f4", name="gear.3mf", source="model", size_bytes=412003,
                  added_s=NOW_S - 900),
]
EVENTS = [
    s.Event(seq=1, t_sim_s=2.7, kind="started", data={"rows": 11898, "estimate_s": 1587.2}),
    s.Event(seq=2, t_sim_s=5.8, kind="layer", layer=0, gcode_line=8, data={"z_mm": 0.5}),
    s.Event(seq=3, t_sim_s=325.8, kind="temp_reached", layer=0, gcode_line=10, data={"heater": "bed", "temp_c": 59}),
    s.Event(seq=4, t_sim_s=325.8, kind="temp_reached", layer=0, gcode_line=11,
            data={"heater": "nozzle", "temp_c": 215}),
    s.Event(seq=5, t_sim_s=465.5, kind="layer", layer=1, gcode_line=464, data={"z_mm": 1.7}),
    s.Event(seq=6, t_sim_s=480.0, kind="override", layer=1, data={"speed_r": 1.5}),
    s.Event(seq=7, t_sim_s=517.1, kind="layer", layer=2, gcode_line=848, data={"z_mm": 2.3}),
    s.Event(seq=8, t_sim_s=530.2, kind="paused", layer=2, gcode_line=900, data={"reason": "operator"}),
]


def frozen_console() -> FabricConsole:
    ticks = itertools.count(0.0, 15.0)          # each temperature sample 15 s after the last
    return FabricConsole(None, files_root=SAMPLES_DIR, wall_clock=lambda: NOW_S,
                         monotonic_clock=lambda: next(ticks))


async def first_screen(pilot) -> None:
    """What a new operator sees first: an idle station, nothing loaded, nothing on the plate."""
    app: FabricConsole = pilot.app
    app.cell, app.sub_title = "cell1", "cell cell1"
    app.alive = {name: True for name in ("station", "slicer", "planner", "collision", "supervisor")}
    app.station_state = s.StationState(state="idle", rtf=1.0)
    app.temps = s.Temps(nozzle_c=25.0, nozzle_target_c=0.0, bed_c=25.0, bed_target_c=0.0)
    await pilot.pause()


async def fill(pilot, screen: str) -> None:
    app: FabricConsole = pilot.app
    app.cell = "cell1"
    app.sub_title = "cell cell1"
    app.alive = {"station": True, "slicer": True, "planner": True, "collision": True, "supervisor": False}
    app.limits = ([-180.0, -90.0, -230.0, -200.0, -115.0, -400.0], [180.0, 110.0, 50.0, 200.0, 115.0, 400.0])
    app.toolpath = square_layers()
    app.station_state = s.StationState(state="printing", program_id="p", job_id="a1b2c3d4e5f6", t_sim_s=530.0,
                                       elapsed_s=527.0, total_s=1587.0, remaining_s=1060.0, progress_r=0.31,
                                       deposited_mm3=2024.0, planned_mm3=6529.0, layer=2, layers_total=4,
                                       rtf=10.0, speed_r=1.5, flow_r=1.0)
    for k in range(21):
        app.temps = s.Temps(nozzle_c=min(215.0, 25 + 19 * k), nozzle_target_c=215.0, bed_c=min(60.0, 25 + 4 * k),
                            bed_target_c=60.0, t_sim_s=10.0 * k)
    app.pose = s.Pose(seq=100, t_sim_s=530.0, q_deg=[12.5, 35.2, -20.1, 0.4, 108.0, -12.0],
                      xyz_mm=[120.0, 90.0, 0.9], quat_wxyz=[0.0, 1.0, 0.0, 0.0], base_xyz_mm=[480.0, 10.0, 200.0])
    app.extrusion = s.Extrusion(seq=50, t_sim_s=530.0, on=True, flow_mm3_s=4.25, extruded_mm3=2024.0,
                                filament_mm=841.0, layer=2, row=19, gcode_line=900, flow_r=1.0)
    app.jobs = list(JOBS)
    for e in EVENTS:
        app.add_log(f"event #{e.seq} {e.kind}")
    app.show_reply("overrides", True, "speed x1.50  flow x1.00  rtf 10")
    await app.switch_mode(screen)
    if screen == "events":
        app.screen.show_events(None, EVENTS)
    if screen == "files":
        app.screen.show_files(s.FileList(files=FILES, total=len(FILES)))
    await pilot.pause()


@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize("screen", ["cell", "jobs", "events", "log", "files"])
def test_screen_snapshot(snap_compare, screen, size):
    async def run_before(pilot) -> None:
        await fill(pilot, screen)
    assert snap_compare(frozen_console(), terminal_size=SIZES[size], run_before=run_before)


@pytest.mark.parametrize("size", SIZES)
def test_first_screen_snapshot(snap_compare, size):
    """Issue 24: the first screen said only IDLE / no program loaded."""
    assert snap_compare(frozen_console(), terminal_size=SIZES[size], run_before=first_screen)


async def job_record(pilot) -> None:
    await fill(pilot, "jobs")
    history = pilot.app.screen.query_one("#history")
    history.focus()
    history.move_cursor(row=0)
    await pilot.press("enter")
    await pilot.pause()


async def submit_dialog(pilot) -> None:
    await first_screen(pilot)
    await pilot.press("a")
    while not isinstance(pilot.app.screen, SubmitDialog) or not pilot.app.screen.query("#submit-sample"):
        await pilot.pause(0.05)
    tree = pilot.app.screen.query_one("#submit-tree")
    while len(tree.root.children) < 2:                  # the folder is read in a worker
        await pilot.pause(0.05)
    await pilot.pause(0.3)


async def help_dialog(pilot) -> None:
    await first_screen(pilot)
    await pilot.press("question_mark")
    await pilot.pause()


async def paused_print(pilot) -> None:
    """Paused: the ETA line says the wall-clock time left once resumed (not simulated time)."""
    await fill(pilot, "cell")
    app = pilot.app
    app.station_state = s.StationState(state="paused", reason="paused by operator", program_id="p",
                                       job_id="a1b2c3d4e5f6", t_sim_s=530.0, elapsed_s=527.0, total_s=1587.0,
                                       remaining_s=1060.0, progress_r=0.31, deposited_mm3=2024.0,
                                       planned_mm3=6529.0, layer=2, layers_total=4, rtf=10.0, speed_r=1.5)
    await pilot.pause()


async def next_job_question(pilot) -> None:
    """A confirmation whose question is longer than a line (it was cut to one line at 80x24)."""
    await fill(pilot, "jobs")
    app = pilot.app
    app.station_state = s.StationState(state="idle", reason="finished", plate_clear=False, plate_mm3=10355.0,
                                       plate_job_id="ffdd71c51965", rtf=10.0)
    await pilot.pause()
    await pilot.press("n")
    await pilot.pause()


@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize("name", ["job-record", "submit", "help", "paused", "confirm"])
def test_dialog_snapshot(snap_compare, name, size):
    before = {"job-record": job_record, "submit": submit_dialog, "help": help_dialog, "paused": paused_print,
              "confirm": next_job_question}[name]
    assert snap_compare(frozen_console(), terminal_size=SIZES[size], run_before=before)


async def collision_hit(pilot) -> None:
    """Issue 18: the program loaded, not printing, a check found a travel through layer 2: the layer view shows
    that layer, the hit marked where it is, its border title says where."""
    await fill(pilot, "cell")
    app = pilot.app
    app.station_state = s.StationState(state="ready", reason="loaded 33 rows", program_id="p", total_s=1587.0,
                                       remaining_s=1587.0, planned_mm3=6529.0, layers_total=4, rtf=10.0)
    hit = s.CollisionHit(body_a="tool_nozzle", body_b="part", t_s=312.4, row=14, gcode_line=345, layer=1,
                         move_r=0.4, kind="travel", xyz_mm=[100.0, 110.0, 1.6], distance_mm=-0.2, bead=9,
                         bead_layer=1, bead_gcode_line=331,
                         message="G-code line 345 (travel, layer 2): tool_nozzle hits the part (a bead of layer 2 "
                                 "laid by G-code line 331) with the nozzle at (100.0, 110.0, 1.6) mm, t = 312.4 s")
    report = s.CollisionReport(collision_free=False, checked_configs=1200, min_distance_mm=0.0, first_hit=hit)
    app.post_message(CollisionChecked("cell1", "p", report))
    app.show_reply("collisions", True, f"COLLISION at {hit.message}", "error")
    await pilot.pause()


@pytest.mark.parametrize("size", SIZES)
def test_collision_hit_snapshot(snap_compare, size):
    assert snap_compare(frozen_console(), terminal_size=SIZES[size], run_before=collision_hit)
