"""Planner: G-code -> verified joint program, checked against independent Pinocchio forward kinematics."""
from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from fabric.motion.program import MOVEJ, MOVEL, PRINT, RETRACT, SET_TEMP, WAIT_TEMP
from fabric.planning import PlanOptions, plan_gcode, plan_gcode_file
from fabric.robot.cell import Cell
from fabric.robot.kinematics import IK_OK
from fabric.wire.errors import UnreachableError, ValidationError


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


def _reference_positions(text: str) -> dict[int, np.ndarray]:
    """Position after every line, from a plain sequential interpreter (G90/G91/G92/G28, G0/G1 only)."""
    pos, off, absolute = np.zeros(3), np.zeros(3), True
    out: dict[int, np.ndarray] = {}
    for n, raw in enumerate(text.splitlines(), start=1):
        code = raw.split(";")[0].strip().upper()
        words = dict((w[0], w[1:]) for w in code.split() if w)
        cmd = code.split()[0] if code else ""
        axes = {a: float(words[a]) for a in "XYZ" if a in words}
        if cmd in ("G0", "G1"):
            for i, a in enumerate("XYZ"):
                if a in axes:
                    pos[i] = axes[a] + off[i] if absolute else pos[i] + axes[a]
        elif cmd == "G90":
            absolute = True
        elif cmd == "G91":
            absolute = False
        elif cmd == "G92":
            for i, a in enumerate("XYZ"):
                if a in axes:
                    off[i] = pos[i] - axes[a]
        elif cmd == "G28":
            pos[:] = 0.0
            off[:] = 0.0
        out[n] = pos.copy()
    return out


def _pinocchio_tcp_plate(cell: Cell, q: np.ndarray) -> np.ndarray:
    """TCP poses (N, 4, 4) in the plate frame, mm: Pinocchio on the exported URDF, independently."""
    import pinocchio as pin
    model = pin.buildModelFromXML(cell.robot.urdf_text())
    data = model.createData()
    fid = model.getFrameId("tcp")
    T = np.empty((len(q), 4, 4))
    for i, qi in enumerate(q):
        pin.framesForwardKinematics(model, data, qi)
        T[i] = data.oMf[fid].homogeneous
    T[:, :3, 3] *= 1000.0
    return np.linalg.inv(cell.wobj_T()) @ T


def _slice(binary: str, stl: Path, out: Path) -> str:
    exe = shutil.which(binary)
    if exe is None:
        pytest.skip(f"{binary} not installed")
    args = [exe, "--export-gcode", str(stl), "-o", str(out)] if binary == "prusa-slicer" \
        else [exe, str(stl), "-o", str(out)]
    subprocess.run(args, check=True, capture_output=True, timeout=60)
    return out.read_text()


def _part(kind: str, path: Path) -> Path:
    import trimesh
    if kind == "box":
        mesh = trimesh.creation.box((20, 20, 12))
    elif kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=9, height=8, sections=48)
    else:                                   # an L: two boxes
        a = trimesh.creation.box((30, 10, 6))
        b = trimesh.creation.box((10, 30, 6))
        b.apply_translation((-10, 10, 0))
        mesh = trimesh.util.concatenate([a, b])
    mesh.apply_translation((0, 0, -mesh.bounds[0, 2]))
    mesh.export(path)
    return path


@pytest.mark.slicers
@pytest.mark.parametrize("binary, kind, tilt", [
    ("prusa-slicer", "box", (0.0, 0.0)), ("slic3r", "box", (0.0, 0.0)),
    ("prusa-slicer", "cylinder", (5.0, 0.0)), ("slic3r", "L", (0.0, -5.0)),
])
def test_acceptance_fk_of_every_target_matches_the_gcode(tmp_path: Path, cell: Cell, binary: str, kind: str,
                                                          tilt: tuple[float, float]) -> None:
    """Issue text: FK of every planned target (Pinocchio, exported URDF) is the G-code point within
    0.01 mm in the plate frame, with the nozzle axis within 0.01 deg of the requested one."""
    text = _slice(binary, _part(kind, tmp_path / f"{kind}.stl"), tmp_path / f"{kind}.gcode")
    diameter = float(re.search(r"; filament_diameter = ([\d.]+)", text).group(1))   # Slic3r's default is 3 mm
    opt = PlanOptions(offset_mm=(25.0, 25.0, 0.0), tilt_deg=tilt, travel_lift_mm=0.8, filament_diameter_mm=diameter)
    res = plan_gcode(text, cell, opt).require_runnable()
    prog = res.program
    motion = np.flatnonzero(prog.op <= MOVEL)
    assert res.report.status[motion[:-1]].tolist() == [IK_OK] * (len(motion) - 1)
    T = _pinocchio_tcp_plate(cell, prog.q_rad[motion])
    # every target: FK = the planned target, nozzle along the requested axis
    assert np.abs(T[:, :3, 3] - prog.xyz_mm[motion]).max() < 0.01
    axis = opt.nozzle_axis()
    ang = np.degrees(np.arccos(np.clip(T[:-1, :3, 2] @ axis, -1, 1)))
    assert ang.max() < 0.01
    # print targets: the G-code point (+ offset), lifted travels exactly travel_lift_mm higher
    ref = _reference_positions(text)
    pm = motion[(prog.section[motion] == PRINT)]
    want = np.array([ref[int(ln)] for ln in prog.gcode_line[pm]]) + opt.offset_mm
    got = T[np.searchsorted(motion, pm), :3, 3]
    dz = got[:, 2] - want[:, 2]
    lift = opt.travel_lift_mm
    on_point = (np.abs(got[:, :2] - want[:, :2]).max(axis=1) < 0.01) & (np.abs(dz) < 0.01)
    raised = (np.abs(got[:, :2] - want[:, :2]).max(axis=1) < 0.01) & (np.abs(dz - lift) < 0.01)
    # the vertical lifts that start a lifted travel: straight up from the previous target
    prev = T[np.searchsorted(motion, pm) - 1, :3, 3]
    up = ~on_point & ~raised & (np.abs(got - prev - [0, 0, lift]).max(axis=1) < 0.01)
    assert np.count_nonzero(up) == res.stats.travel_lifts > 0
    # the rest: rows a long move was split into (fabric/planning/refine.py), on that move, before its own row
    rest = np.flatnonzero(~on_point & ~raised & ~up)
    nxt = np.minimum(np.searchsorted(motion, pm[rest]) + 1, len(motion) - 1)
    a, b = prev[rest], T[nxt, :3, 3]
    u = np.einsum("ij,ij->i", got[rest] - a, b - a) / np.einsum("ij,ij->i", b - a, b - a)
    assert np.all((u > 0) & (u < 1)) and np.abs(a + u[:, None] * (b - a) - got[rest]).max(initial=0) < 0.01
    assert np.array_equal(prog.gcode_line[motion[nxt]], prog.gcode_line[pm[rest]])
    assert 0 < len(rest) <= prog.meta["linear_split_rows"]          # (the approach has its own)
    assert np.all((on_point | np.isin(np.arange(len(pm)), rest))[prog.flow_mm3_mm[pm] > 0])
    # extruded volume is the slicer's
    m = re.search(r"; filament used \[mm\] = ([\d.]+)|; filament used = ([\d.]+)mm", text)
    used_mm = float(next(g for g in m.groups() if g))
    assert abs(res.stats.extruded_volume_mm3 / opt.filament_area_mm2 - used_mm) < 0.1
    assert res.estimate_s > res.stats.print_length_mm / opt.max_tcp_speed_mm_s


GCODE = """; test part
M140 S60
M104 S210
G28
G21
G90
M83
G1 Z5 F3000
M190 S60
M109 S210
;LAYER_CHANGE
;Z:0.3
G1 X10 Y10 Z0.3 F6000
G1 X40 Y10 E1.5 F1200
G1 X40 Y40 E1.5
G1 E-0.8 F2400
G1 X100 Y100 F6000
G1 E0.8 F2400
G1 X120 Y100 E1.0 F1800
G1 X121 Y100 F6000
G1 X150 Y100 E1.5 F9000
;LAYER_CHANGE
;Z:0.6
G1 Z0.6 F600
G1 X150 Y150 E2.5 F1800
M104 S0
"""


def test_program_structure_speeds_flow_events(cell: Cell) -> None:
    # moves kept whole (linear_tol_mm: the approach's 50 mm descent would be split, tests/test_refine_linear.py)
    opt = PlanOptions(offset_mm=(20, 20, 0), max_tcp_speed_mm_s=100.0, speed_r=0.5, zone_mm=0.3, linear_tol_mm=10.0)
    res = plan_gcode(GCODE, cell, opt).require_runnable()
    p = res.program
    # Approach: joint move above the first bead, heat and wait there, linear move down to the bead's start
    assert p.section_bounds() == {"Approach": (0, 6), "Print": (6, len(p) - 2), "ReturnHome": (len(p) - 2, len(p))}
    assert p.op[[0, 5, -2, -1]].tolist() == [MOVEJ, MOVEL, MOVEL, MOVEJ]
    assert [(int(o), int(ln)) for o, ln in zip(p.op[1:5], p.gcode_line[1:5], strict=True)] == [
        (SET_TEMP, 2), (SET_TEMP, 3), (WAIT_TEMP, 9), (WAIT_TEMP, 10)]
    assert np.allclose(p.xyz_mm[0:5], [30, 30, 0.3 + cell.approach_height_mm])   # heating up there, clear
    assert np.allclose(p.xyz_mm[5], [30, 30, 0.3]) and p.zone_mm[5] == 0.0        # where line 14's bead starts
    assert p.speed_mm_s[5] == min(cell.approach_speed_mm_s, 100.0) and p.gcode_line[5] == 13
    assert p.meta["leading_travels_dropped"] > 0
    assert np.allclose(p.q_rad[-1], cell.home_q_rad)
    assert np.allclose(p.xyz_mm[-2], p.xyz_mm[-3] + [0, 0, cell.approach_height_mm])
    assert (p.vel_r[[0, -1]] > 0).all() and (p.vel_r[[0, -1]] <= 1).all()
    # events became rows before their moves, with their G-code lines
    ev = p.op[6:-2]
    lines = p.gcode_line[6:-2]
    assert [(int(o), int(ln)) for o, ln in zip(ev, lines, strict=True) if o > MOVEL] == [
        (RETRACT, 16), (RETRACT, 18), (SET_TEMP, 26)]
    assert p.value[(p.op == RETRACT)].tolist() == [-0.8, 0.8]
    # speeds: feed * speed_r, capped; flow per mm from E
    row = int(np.flatnonzero(p.gcode_line == 14)[0])
    assert np.isclose(p.speed_mm_s[row], 1200 / 60 * 0.5)
    assert np.isclose(p.flow_mm3_mm[row], 1.5 * np.pi * 1.75 ** 2 / 4 / 30.0)
    row = int(np.flatnonzero(p.gcode_line == 21)[0])
    assert np.isclose(p.speed_mm_s[row], 9000 / 60 * 0.5)          # 75 < cap 100
    assert p.speed_mm_s.max() <= 100.0 + 1e-9
    # travel lift: the 85 mm travel goes up, across, down; the 1 mm one does not
    trav = np.flatnonzero(p.gcode_line == 17)
    assert len(trav) == 3 and np.allclose(p.xyz_mm[trav, 2], [1.3, 1.3, 0.3])
    assert len(np.flatnonzero(p.gcode_line == 20)) == 1
    assert res.stats.travel_lifts == 1                   # this one; the travel to the first bead became the approach
    assert np.isclose(res.stats.extruded_volume_mm3, 8.0 * np.pi * 1.75 ** 2 / 4)
    assert res.stats.layers == 2 and set(p.layer[p.section == PRINT]) >= {0, 1}
    # the estimate is the motion model's, with the heat-up waits in it
    from fabric.motion.timing import StartState, time_program
    tl = time_program(p, cell.robot, 1.0, start_state=StartState.at_joints(cell.robot, p.wobj, cell.home_q_rad))
    assert np.isclose(res.estimate_s, tl.total_s)
    assert res.estimate_s > res.stats.path_length_mm / 100.0


def test_unreachable_point_names_its_line(cell: Cell) -> None:
    text = GCODE.replace("G1 X100 Y100 F6000", "G1 X900 Y100 F6000")     # 900 mm: off the plate, out of reach
    res = plan_gcode(text, cell, PlanOptions())
    assert res.report.first_unreachable is not None
    with pytest.raises(UnreachableError) as ei:
        res.require_runnable()
    assert ei.value.details["gcode_line"] == 17
    assert ei.value.details["reason"] == "off the plate"              # the envelope speaks first
    assert "line 17" in str(ei.value)
    assert res.report.feasible_r < 1.0 and np.isnan(res.estimate_s)
    allowed = plan_gcode(text, cell, PlanOptions(allow_off_plate=True))   # allowed: the robot still cannot
    with pytest.raises(UnreachableError) as ei:
        allowed.require_runnable()
    assert (ei.value.details["gcode_line"], ei.value.details["reason"]) == (17, "out of reach")
    assert allowed.report.counts["off the plate"] >= 1


def test_blocks_of_ik_give_the_same_program(cell: Cell, tmp_path: Path) -> None:
    lines = ["M83", "G1 Z0.3 F3000"]
    rng = np.random.default_rng(1)
    walk = np.clip(125 + np.cumsum(rng.uniform(-4, 4, (2500, 2)), axis=0), 10, 240)
    for x, y in walk:
        lines.append(f"G1 X{x:.3f} Y{y:.3f} E0.05 F{rng.integers(900, 3000)}")
    text = "\n".join(lines) + "\n"
    (tmp_path / "r.gcode").write_text(text)
    seen: list[float] = []
    one = plan_gcode(text, cell, PlanOptions(travel_lift_mm=0.0))
    many = plan_gcode_file(tmp_path / "r.gcode", cell, PlanOptions(travel_lift_mm=0.0, ik_block_rows=1000),
                           progress=seen.append)
    assert many.program.meta["name"] == "r" and many.program.meta["filename"] == "r.gcode"
    assert np.allclose(one.program.q_rad, many.program.q_rad, atol=1e-9)
    assert many.report.reachable
    assert seen == sorted(seen) and seen[-1] == 1.0 and len(seen) >= 4


@pytest.mark.parametrize("kw", [dict(offset_mm=(1, 2)), dict(speed_r=0), dict(tilt_deg=(95, 0)),
                                dict(rot_range_deg=(10, -10)), dict(filament_diameter_mm=-1),
                                dict(approach_height_mm=0), dict(zone_mm=float("nan"))])
def test_options_are_validated(kw: dict) -> None:
    with pytest.raises(ValidationError) as ei:
        PlanOptions(**kw)
    assert ei.value.details["field"] in kw


def test_empty_gcode_is_an_error(cell: Cell) -> None:
    with pytest.raises(ValidationError):
        plan_gcode("; nothing to print\nM104 S200\n", cell)


def test_joint_speed_limits_slow_linear_moves_and_say_where() -> None:
    """A fast move the (deliberately slow) A1 cannot follow is slowed, and the plan names its line."""
    slow = Cell.builtin("irb140")
    vel = slow.robot.vel_limit_rad_s.copy()
    vel[0] = np.radians(5.0)                           # A1 at 5 deg/s
    slow.robot.with_limits(vel_limit_rad_s=vel)
    text = "G21\nG90\nM83\nG1 Z0.5 F600\nG1 X60 Y125 F3000\nG1 X190 Y60 E5 F12000\nG1 X190 Y190 E5\n"
    res = plan_gcode(text, slow, PlanOptions())
    assert res.slowed_rows is not None and len(res.slowed_rows) > 0
    lines = res.program.gcode_line[res.slowed_rows]
    assert 6 in lines.tolist() and 0 in res.slowed_joint.tolist()     # the sweep across the plate, A1
    fast = plan_gcode(text, Cell.builtin("irb140"), PlanOptions())
    assert res.estimate_s > fast.estimate_s


def _layers_gcode(first_z_mm: float, layers: int, spacing_mm: float = 0.3) -> str:
    """A small square, ``layers`` layers from ``first_z_mm`` up, extruding."""
    out = ["G21", "G90", "M83", "G1 X100 Y100 F3000"]
    for k in range(layers):
        out += [f";LAYER_CHANGE\nG1 Z{first_z_mm + k * spacing_mm:.3f}", "G1 X110 Y100 E0.5 F1200",
                "G1 X110 Y110 E0.5", "G1 X100 Y110 E0.5", "G1 X100 Y100 E0.5"]
    return "\n".join(out) + "\n"


def test_a_first_layer_laid_well_above_the_plate_is_warned_of(cell):
    """``--offset 0 0 500`` planned a part 500 mm up, runnable, without a word: its beads go down onto nothing.
    A first layer on the plate (or lifted within two layer spacings and half a millimetre) gets no warning."""
    def warnings(text: str, offset=(0.0, 0.0, 0.0)) -> list[str]:
        res = plan_gcode(text.encode(), cell, PlanOptions(offset_mm=offset))
        return [w for w in res.stats.warnings if "first layer" in w]

    assert warnings(_layers_gcode(0.3, 3)) == []
    assert warnings(_layers_gcode(0.3, 3), offset=(0.0, 0.0, 0.7)) == []           # 1.0 mm: within 2 x 0.3 + 0.5
    lifted = warnings(_layers_gcode(0.3, 3), offset=(0.0, 0.0, 50.0))
    assert lifted == ["the first layer is laid 50.3 mm above the plate, layers 0.30 mm apart: its beads go down "
                      "onto nothing unless an object is placed there first (--offset Z lifts the part)"]
    assert warnings(_layers_gcode(10.0, 3, spacing_mm=10.0)) == []                # concrete: 10 mm layers
    assert warnings(_layers_gcode(0.3, 1), offset=(0.0, 0.0, 20.0))                # one layer, 20.3 mm up
