"""Cell files: the shipped cells, strict parsing, frames, URDF export, built-in names, and the UR5 path."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from fabric.robot.cell import CELLS_DIR, Cell, builtin_cell_names
from fabric.robot.kinematics import IK_OK
from fabric.robot.numeric import NumericIK
from fabric.robot.path_ik import solve_path
from fabric.wire.errors import ConfigError, NotFound

IRB_TEXT = (CELLS_DIR / "irb140.toml").read_text()


@pytest.fixture(scope="module")
def irb() -> Cell:
    return Cell.builtin("irb140")


@pytest.fixture(scope="module")
def ur5() -> Cell:
    return Cell.builtin("ur5")


def test_irb140_cell_is_the_papers_layout(irb: Cell) -> None:
    assert irb.robot.closed_form is not None and irb.robot.name == "irb140"
    np.testing.assert_allclose(irb.base_T, np.eye(4))
    np.testing.assert_allclose(irb.table_T[:3, 3], [310, 0, 0])
    np.testing.assert_allclose(irb.plate_T[:3, 3], [600, 0, 0])
    np.testing.assert_allclose(irb.plate_size_mm, [250, 250, 10])
    np.testing.assert_allclose(irb.wobj_T()[:3, 3], [475, -125, 10])           # top-face corner, x/y min
    np.testing.assert_allclose(irb.wobj_T()[:3, :3], np.eye(3))
    assert irb.approach_speed_mm_s == 150.0 and irb.approach_zone_mm == 0.0
    np.testing.assert_allclose(irb.robot.tool_T[:3, 3], [0, 0, 150])


@pytest.mark.parametrize("name", ["irb140", "irb140-multiaxis", "ur5", "ur10", "kr6r700", "panda", "fr3"])
def test_home_is_within_limits_clear_of_the_plate_and_collision_free(name: str) -> None:
    cell = Cell.builtin(name)
    r = cell.robot
    assert r.within_limits(cell.home_q_rad)[0]
    tcp = cell.home_tcp_T()
    assert tcp[2, 3] > cell.plate_T[2, 3] + cell.plate_size_mm[2] + 200.0       # well above the plate
    np.testing.assert_allclose(tcp[:3, 2], [0, 0, -1], atol=1e-9)              # nozzle down
    gd = r.collision_model.createData()
    assert not pin.computeCollisions(r.pin_model, r.pin_data, r.collision_model, gd, cell.home_q_rad, True)


def test_to_dict_is_plain_and_has_the_work_object(irb: Cell) -> None:
    d = json.loads(json.dumps(irb.to_dict()))
    assert d["wobj"] == {"xyz_mm": [475.0, -125.0, 10.0], "rpy_deg": [0.0, 0.0, 0.0]}
    assert d["robot"]["upper_deg"] == [180.0, 110.0, 50.0, 200.0, 115.0, 400.0]
    assert d["approach"]["zone"] == "fine" and d["source_path"].endswith("irb140.toml")


@pytest.mark.parametrize("edit, key", [
    (("[plate]\n", "[plate]\ncolour = \"red\"\n"), "plate.colour"),
    (("[plate.true_offset]\n", "[plate.true_offset]\nyaw_deg = 1.0\n"), "plate.true_offset.yaw_deg"),
    (("[home]\n", "[homing]\nspeed = 1\n\n[home]\n"), "homing"),
])
def test_unknown_keys_are_config_errors_naming_them(edit: tuple[str, str], key: str) -> None:
    with pytest.raises(ConfigError) as exc:
        Cell.from_toml_text(IRB_TEXT.replace(*edit, 1))
    assert exc.value.details["key"] == key and key in str(exc.value)


@pytest.mark.parametrize("edit, key", [
    (("speed_mm_s = 150.0", "speed_mm_s = -5.0"), "approach.speed_mm_s"),
    (("speed_mm_s = 150.0", "speed_mm_s = \"fast\""), "approach.speed_mm_s"),
    (("zone = \"fine\"", "zone = \"z1000\""), "approach.zone"),
    (("size_mm = [250.0, 250.0, 10.0]", "size_mm = [250.0, 250.0]"), "plate.size_mm"),
    (("joints_deg = [0.0, 0.0, 0.0, 0.0, 90.0, 0.0]", "joints_deg = [0.0, 0.0, 0.0, 0.0, 130.0, 0.0]"),
     "home.joints_deg"),
    (("urdf = \"robot/urdf/irb140.urdf\"", "urdf = \"robot/urdf/nope.urdf\""), "robot.urdf"),
    (("[approach]", "[limits]\nupper_deg = [180.0, 110.0, 50.0, 200.0, 130.0, 400.0]\n\n[approach]"),
     "limits.upper_deg"),
])
def test_values_are_range_checked(edit: tuple[str, str], key: str) -> None:
    assert edit[0] in IRB_TEXT
    with pytest.raises(ConfigError) as exc:
        Cell.from_toml_text(IRB_TEXT.replace(*edit, 1))
    assert exc.value.details["key"] == key


def test_missing_section_and_unknown_builtin() -> None:
    with pytest.raises(ConfigError) as exc:
        Cell.from_toml_text(IRB_TEXT.replace("[home]\n", "[home_was_here]\n").replace(
            "joints_deg = [0.0, 0.0, 0.0, 0.0, 90.0, 0.0]", ""))
    assert exc.value.details["key"] == "home_was_here"
    with pytest.raises(NotFound):
        Cell.builtin("kuka")


def test_true_offset_and_limit_overrides() -> None:
    text = IRB_TEXT.replace("xyz_mm = [0.0, 0.0, 0.0]\nrpy_deg = [0.0, 0.0, 0.0]\n\n[home]",
                            "xyz_mm = [1.5, -2.0, 0.5]\nrpy_deg = [0.0, 0.0, 2.0]\n\n[home]")
    text = text.replace("[approach]", "[limits]\nvel_deg_s = [100.0, 100.0, 100.0, 100.0, 100.0, 100.0]\n\n[approach]")
    cell = Cell.from_toml_text(text)
    np.testing.assert_allclose(cell.true_plate_T[:3, 3], [601.5, -2.0, 0.5])
    np.testing.assert_allclose(cell.plate_T[:3, 3], [600.0, 0.0, 0.0])
    yaw = np.degrees(np.arctan2(cell.true_plate_T[1, 0], cell.true_plate_T[0, 0]))
    assert yaw == pytest.approx(2.0)
    np.testing.assert_allclose(np.degrees(cell.robot.vel_limit_rad_s), 100.0)
    assert not np.allclose(cell.true_wobj_T(), cell.wobj_T())


@pytest.mark.parametrize("name", ["irb140", "ur5", "ur10", "kr6r700"])
def test_exported_urdf_reloads_with_the_same_tcp(name: str, tmp_path: Path) -> None:
    cell = Cell.builtin(name)
    r = cell.robot
    path = tmp_path / f"{name}.urdf"
    r.export_urdf(path)
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    geom = pin.buildGeomFromUrdf(model, str(path), pin.GeometryType.COLLISION, package_dirs=r.package_dirs)
    assert geom.ngeoms == r.collision_model.ngeoms
    fid = model.getFrameId("tcp")
    rng = np.random.default_rng(11)
    q = rng.uniform(np.maximum(r.lower_rad, -np.pi), np.minimum(r.upper_rad, np.pi), (10, r.nq))
    ours = r.fk(q)
    for i in range(len(q)):
        pin.framesForwardKinematics(model, data, q[i])
        T = data.oMf[fid].homogeneous.copy()
        T[:3, 3] *= 1000.0
        np.testing.assert_allclose(T, ours[i], atol=1e-9)


def test_ur5_closed_form_ik_round_trip_agrees_with_numeric_ik(ur5: Cell) -> None:
    r = ur5.robot
    assert r.ik_family == "ur" and r.closed_form is not None and r.flange_frame == "tool0"
    rng = np.random.default_rng(12)
    q = ur5.home_q_rad + np.cumsum(rng.normal(0.0, 0.02, (40, 6)), axis=0)   # a wandering joint path
    T = r.fk(q)
    for solver in (r.solver, NumericIK(r.pin_model, r.lower_rad, r.upper_rad, r.tcp_frame_id)):
        qs, st = solver.solve(T, q[0])
        assert np.all(st == IK_OK)
        back = r.fk(qs)
        np.testing.assert_allclose(back[:, :3, 3], T[:, :3, 3], atol=1e-3)    # mm (numeric solver: 1e-7 m)
        np.testing.assert_allclose(back[:, :3, :3], T[:, :3, :3], atol=1e-6)
        np.testing.assert_allclose(qs, q, atol=1e-4)                           # continuity keeps the branch
    far = T[:1].copy()
    far[0, :3, 3] = [3000.0, 0.0, 0.0]
    assert r.ik(far, q[0])[1][0] != IK_OK


@pytest.mark.parametrize("name", ["irb140", "irb140-multiaxis", "ur5", "ur10", "kr6r700", "panda", "fr3"])
def test_plate_and_200_mm_above_are_reachable_with_a_vertical_nozzle(name: str) -> None:
    cell = Cell.builtin(name)
    W = cell.wobj_T()
    u = np.linspace(0.0, 250.0, 11)
    X, Y = np.meshgrid(u, u)
    X[1::2] = X[1::2, ::-1]
    for z in (0.3, 100.0, 200.0):                                   # one serpentine layer per height
        pts = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, z)])
        xyz = pts @ W[:3, :3].T + W[:3, 3]
        res = solve_path(cell.robot, xyz, [0.0, 0.0, -1.0], cell.home_q_rad)
        assert res.feasible_r == 1.0, (z, res.status)
        assert cell.robot.closed_form is not None                   # every built-in cell has a closed form
        np.testing.assert_allclose(cell.robot.fk(res.q_rad)[:, :3, 3], xyz, atol=1e-6)
    sx, sy, _ = cell.plate_size_mm                                  # the plate lies on the table
    corners = cell.plate_T[:3, 3][:2] + np.array([[-sx, -sy], [sx, sy]]) / 2.0
    lo = cell.table_T[:3, 3][:2] - cell.table_size_mm[:2] / 2.0
    hi = cell.table_T[:3, 3][:2] + cell.table_size_mm[:2] / 2.0
    assert np.all(corners >= lo) and np.all(corners <= hi)


@pytest.mark.slow                         # 1.5 s (not the fast tier)
def test_load_or_builtin_reads_the_cell_config_option(irb: Cell, tmp_path: Path) -> None:
    assert Cell.load_or_builtin(None).source_path == irb.source_path          # no option: the built-in IRB 140
    assert Cell.load_or_builtin("").robot.name == "irb140"
    assert Cell.load_or_builtin(CELLS_DIR / "ur5.toml").robot.name == "ur5"
    with pytest.raises(NotFound):
        Cell.load_or_builtin(tmp_path / "missing.toml")
    for name, family, nq in (("irb140", "opw", 6), ("ur5", "ur", 6), ("ur10", "ur", 6), ("kr6r700", "opw", 6),
                             ("panda", "panda", 7), ("fr3", "panda", 7)):
        cell = Cell.load_or_builtin(name)                                      # a built-in by name
        assert cell.name == name and cell.robot.ik_family == family and cell.robot.nq == nq
        assert cell.to_dict()["robot"]["ik_family"] == family
    assert builtin_cell_names() == ["fr3", "irb140", "irb140-multiaxis", "kr6r700", "panda", "ur10", "ur5"]
    with pytest.raises(NotFound) as exc:
        Cell.load_or_builtin("kuka")
    assert exc.value.details["known"] == builtin_cell_names()
    (tmp_path / "ur5").write_text((CELLS_DIR / "irb140.toml").read_text())
    assert Cell.load_or_builtin(tmp_path / "ur5").robot.name == "irb140"      # an existing file wins


@pytest.mark.slow                         # 2.4 s (not the fast tier)
def test_cell_list_prints_the_builtin_cells(capsys: pytest.CaptureFixture[str]) -> None:
    from fabric.cli.main import main
    assert main(["cell", "list", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [(r["cell"], r["robot"], r["joints"], r["ik_family"], r["export"]) for r in rows] == [
        ("fr3", "fr3", 7, "panda", "csv"),
        ("irb140", "irb140", 6, "opw", "rapid"), ("irb140-multiaxis", "irb140", 6, "opw", "rapid"),
        ("kr6r700", "kr6r700", 6, "opw", "krl"),
        ("panda", "panda", 7, "panda", "csv"), ("ur10", "ur10", 6, "ur", "urscript"),
        ("ur5", "ur5", 6, "ur", "urscript")]
    assert [r["default"] for r in rows] == [False, True, False, False, False, False, False]
    assert main(["cell", "list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["fr3", "fr3", "7", "joints", "IK", "panda", "export", "csv"]
    assert lines[1].split() == ["irb140", "irb140", "6", "joints", "IK", "opw", "export", "rapid", "(default)"]


@pytest.mark.parametrize("service", ["station", "slicer", "planner", "collision"])
def test_every_service_that_needs_the_cell_takes_cell_config(service: str) -> None:
    from fabric.cli.main import service_parser
    opts = service_parser(service).parse_args(["--cell-config", "mycell.toml"])
    assert opts.cell_config == "mycell.toml"
    assert service_parser(service).parse_args([]).cell_config is None
