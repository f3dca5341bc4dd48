"""Small things a user tripped over (issue 17, item 7), each now a clear line: `ready`'s exit code, the
size-limit hint, an empty input, an out-of-range set point, the line of an off-plate target, a model
re-centred on the plate, and what an interrupted job has deposited."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from fabric import schemas as s
from fabric.cli.inputs import LIMIT_ENV, read_input, read_whole
from fabric.cli.main import main
from fabric.client import Client
from fabric.motion.testprog import square_program
from fabric.planning import plan_gcode
from fabric.printjobs.events import apply_event
from fabric.robot.cell import Cell
from fabric.services.planner import PlannerService
from fabric.services.slicer import SlicerService
from fabric.services.station import StationService
from fabric.sim.twin import Twin
from fabric.slicing import load_profile, slice_model
from fabric.slicing.placement import Placement
from fabric.slicing.samples import box, to_stl_bytes
from fabric.wire.errors import BadRequest, GcodeError, MeshError, UnreachableError, ValidationError

pytestmark = pytest.mark.timeout(180)

HEAD = "G21\nG90\nM83\n"


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


def cli_args(settings) -> list[str]:
    return replace(settings, mode="client").to_args()


# -- ready: NOT READY is not success -----------------------------------------------------------------

def test_ready_exits_2_when_not_ready(session, settings, cell: Cell, tmp_path: Path, capsys) -> None:
    station = StationService(session, settings.cell, cell, data_dir=tmp_path / "station")
    station.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station",), deadline_s=20)
            assert not client.ready().ready                  # nothing loaded
        assert main(["ready", *cli_args(settings)]) == 2
        assert capsys.readouterr().out.startswith("station NOT READY")
        assert main(["ready", "--json", *cli_args(settings)]) == 2
        assert json.loads(capsys.readouterr().out)["ready"] is False
    finally:
        station.close()


# -- inputs: the limit's hint names what really sets it; an empty file is named --------------------------

def test_the_size_limit_error_names_what_sets_the_limit(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    huge = tmp_path / "huge.gcode"
    with open(huge, "wb") as f:                  # sparse: 600 MB that take no disk
        f.truncate(600 << 20)
    with pytest.raises(ValidationError) as err:
        read_input(str(huge))
    assert str(err.value).endswith("more than the limit of 512 MiB (the most the planner accepts)")
    model = tmp_path / "part.stl"
    with open(model, "wb") as f:
        f.truncate(300 << 20)
    with pytest.raises(ValidationError) as err:
        read_whole(str(model))
    assert "(the most the slicer accepts)" in str(err.value)
    monkeypatch.setenv(LIMIT_ENV, "0.001")
    small = tmp_path / "small.gcode"
    small.write_text(HEAD + "G1 X1 E1\n" * 200)
    with pytest.raises(ValidationError) as err:
        read_input(str(small))
    assert "(as FABRIC_MAX_INPUT_MB=0.001 sets it)" in str(err.value) and "--max-size-mb" not in str(err.value)


def test_an_empty_file_is_named(session, settings, cell: Cell, tmp_path: Path, capsys) -> None:
    empty = tmp_path / "empty.gcode"
    empty.write_bytes(b"")
    with pytest.raises(GcodeError, match=r"empty\.gcode is empty: there is no G-code in it"):
        read_input(str(empty))
    (tmp_path / "empty.stl").write_bytes(b"")
    with pytest.raises(MeshError) as err:
        read_whole(str(tmp_path / "empty.stl"))
    assert err.value.details["reason"] == "empty" and "empty.stl is empty" in str(err.value)
    planner = PlannerService(session, settings.cell, cell, data_dir=tmp_path / "planner")
    planner.start()
    try:
        assert main(["plan", str(empty), *cli_args(settings)]) == 1
        assert f"error [gcode]: {empty} is empty: there is no G-code in it" in capsys.readouterr().err
        with Client.connect(settings) as client:             # a request with no G-code names its file
            client.wait_alive(("planner",), deadline_s=20)
            with pytest.raises(BadRequest, match=r"no G-code to plan in 'empty\.gcode': it is empty"):
                client.plan(s.PlanRequest(gcode=b"", filename="empty.gcode"))
    finally:
        planner.close()


# -- planning: the line of an out-of-range set point and of an off-plate first target -------------------

@pytest.mark.parametrize("code, line, text", [("M104 S999", 4, "M104 S999"), ("M109 S301", 4, "M109 S301"),
                                              ("M104 S200\nM140 S150", 5, "M140 S150")])
def test_a_set_point_above_the_heater_names_its_line(cell: Cell, code: str, line: int, text: str) -> None:
    with pytest.raises(GcodeError) as err:
        plan_gcode(HEAD + code + "\nG1 X100 Y100 Z0.3 F3000\nG1 X120 Y100 E1\n", cell)
    assert err.value.details["line"] == line and err.value.details["text"] == text
    assert str(err.value).startswith(f"line {line}: ") and "heater's maximum" in str(err.value)


def test_an_off_plate_first_target_names_its_line_not_minus_one(cell: Cell) -> None:
    res = plan_gcode(HEAD + "G1 X300 Y100 Z0.3 F3000\nG1 X320 Y100 E1\nG1 X120 Y100 E1\n", cell)
    assert res.report.first_unreachable == (4, "off the plate")      # the approach above line 4's point
    with pytest.raises(UnreachableError) as err:
        res.require_runnable()
    assert err.value.details["gcode_line"] == 4 and str(err.value).startswith("G-code line 4: ")


# -- slicing: a model far off the plate is moved with a word ----------------------------------------------

def test_a_model_off_the_plate_is_recentred_with_a_warning(session, settings, tmp_path: Path, capsys) -> None:
    far = box((20.0, 20.0, 4.0))
    far.apply_translation((1000.0, 40.0, 0.0))
    profile = load_profile("taz-pla-medium")
    res = slice_model(to_stl_bytes(far), "far.stl", profile)
    note = [w for w in res.warnings if "off the 250 x 250 mm plate" in w]
    assert note == ["the model lies off the 250 x 250 mm plate (X 990.0 to 1010.0, Y 30.0 to 50.0 mm): centred on "
                    "the plate, moved by (-875.0, 85.0) mm (--center X Y places it elsewhere)"]
    assert res.bbox_mm[0][0] == pytest.approx(115.0)
    near = box((20.0, 20.0, 4.0))                    # modelled about the origin: touching the plate, no word
    assert not [w for w in slice_model(to_stl_bytes(near), "near.stl", profile).warnings if "off the" in w]
    placed = slice_model(to_stl_bytes(far), "far.stl", profile, placement=Placement(center_xy_mm=(60.0, 60.0)))
    assert not [w for w in placed.warnings if "off the" in w]          # where the user asked: no word
    # and fabric-cli slice prints it
    path = tmp_path / "far.stl"
    path.write_bytes(to_stl_bytes(far))
    slicer = SlicerService(session, settings.cell, (250.0, 250.0), 250.0, data_dir=tmp_path / "slicer")
    slicer.start()
    try:
        assert main(["slice", str(path), "-o", str(tmp_path / "far.gcode"), *cli_args(settings)]) == 0
        assert "  warning: the model lies off the 250 x 250 mm plate" in capsys.readouterr().out
    finally:
        slicer.close()


# -- an interrupted job's record: what it deposited so far ---------------------------------------------

def test_an_interrupted_jobs_record_shows_its_volume_and_progress(cell: Cell) -> None:
    prog = square_program(cell, size_mm=20, layers=3, layer_height_mm=0.5, speed_mm_s=30, nozzle_c=200.0)
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    events: list = []
    while twin.s.job.extruded_mm3 < 50.0:             # hot, some way into the print
        events += twin.advance(0.25)
    assert twin.state == "printing"
    twin.interrupt("the station restarted")
    events += twin.advance(0.0)
    lost = next(e for e in events if e.kind == "interrupted")
    assert lost.data["extruded_mm3"] > 0 and lost.data["extruded_mm3"] == pytest.approx(twin.s.job.extruded_mm3)
    planned = 4 * 20 * 3 * float(prog.flow_mm3_mm.max())         # the square's volume, as planned
    plan = s.PlanSummary(program_id="p", targets=1, moves=1, layers=3, feasible_r=1.0, runnable=True,
                         estimate_s=1.0, extruded_mm3=planned, path_mm=1.0)
    rec = s.JobRecord(job_id="j", filename="sq.gcode", source="gcode", state="printing", started_s=1.0, plan=plan)
    for ev in events:
        apply_event(rec, s.Event(seq=ev.seq, t_sim_s=ev.t_sim_s, kind=ev.kind, row=ev.row,
                                 gcode_line=ev.gcode_line, layer=ev.layer, data=dict(ev.data)), 2.0)
    assert rec.state == "interrupted" and rec.deposited_mm3 == pytest.approx(lost.data["extruded_mm3"])
    assert 0.0 < rec.progress_r < 1.0 and rec.progress_r == pytest.approx(rec.deposited_mm3 / planned)
    assert rec.filament_mm > 0
