"""Linear moves split where interpolating the joints would leave the straight line (fabric/planning/refine.py).

Found by taking the default path: the sample part, sliced with the default profile and planned on the
KR 6 R700, had its nozzle dip 0.3 mm into the plate half-way along a 40 mm line of the first layer (the
twin and the collision check interpolate the joints between rows); the check rightly refused the job.
"""
from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest

from fabric.motion.program import MOVEL, Program
from fabric.planning import PlanOptions, plan_gcode
from fabric.planning.refine import _spread, reach_bound_mm, sag_bound_mm
from fabric.robot.cell import Cell
from fabric.robot.chain_point import ChainPoint
from fabric.robot.kinematics import IK_OK
from fabric.services.planner import PlannerService
from fabric.wire.errors import ValidationError

TOL_MM = 0.05


def long_lines(layers: int = 2, side_mm: float = 60.0) -> str:
    """Squares of 60 mm sides on the plate's middle, a travel of 100 mm between layers: long moves."""
    out = ["G21", "G90", "M83", "M104 S210", "M109 S210"]
    x0 = y0 = 95.0
    for k in range(layers):
        z = 0.3 + 0.25 * k
        out += [f";LAYER:{k}", f"G1 Z{z:.3f} F6000", f"G1 X{x0 if k % 2 == 0 else 30.0} Y{y0} F9000"]
        if k % 2:
            out.append(f"G1 X{x0} Y{y0} F9000")
        for x, y in ((x0 + side_mm, y0), (x0 + side_mm, y0 + side_mm), (x0, y0 + side_mm), (x0, y0)):
            out.append(f"G1 X{x:.3f} Y{y:.3f} E{0.033 * side_mm:.4f} F1800")
    return "\n".join(out) + "\n"


def sag_mm(prog: Program, robot, s: float) -> np.ndarray:
    """How far the TCP of the joints interpolated at ``s`` lies from the straight line, every linear move."""
    r = np.flatnonzero(prog.op[1:] == MOVEL) + 1
    q = prog.q_rad[r - 1] + s * (prog.q_rad[r] - prog.q_rad[r - 1])
    line = prog.xyz_mm[r - 1] + s * (prog.xyz_mm[r] - prog.xyz_mm[r - 1])
    w = prog.wobj
    return np.linalg.norm(robot.fk(q)[:, :3, 3] - (line @ w[:3, :3].T + w[:3, 3]), axis=1)


@pytest.mark.parametrize("name", ["kr6r700", "irb140", "ur5", "panda"])
def test_every_linear_move_stays_on_its_line(name: str) -> None:
    cell = Cell.builtin(name)
    text = long_lines()
    loose = plan_gcode(text, cell, PlanOptions(linear_tol_mm=10.0))
    res = plan_gcode(text, cell, PlanOptions(linear_tol_mm=TOL_MM))
    assert res.report.feasible_r == 1.0
    before = max(sag_mm(loose.program, cell.robot, 0.5))
    assert before > 4 * TOL_MM, f"the test's moves must sag without the split ({before:.3f} mm)"
    for s in (0.25, 0.5, 0.75):
        assert max(sag_mm(res.program, cell.robot, s)) <= TOL_MM
    added = res.program.meta["linear_split_rows"]
    assert added > 0 and len(res.program) == len(loose.program) + added - loose.program.meta["linear_split_rows"]
    # the split changes no figure of the print: volume, path, lines in order, every row solved
    assert res.stats.extruded_volume_mm3 == pytest.approx(loose.stats.extruded_volume_mm3, rel=1e-9)
    assert res.stats.print_length_mm == pytest.approx(loose.stats.print_length_mm, rel=1e-9)
    assert res.program.deposited_volume_mm3() == pytest.approx(loose.program.deposited_volume_mm3(), rel=1e-9)
    lines = res.program.gcode_line[res.program.gcode_line >= 0]
    assert np.all(np.diff(lines) >= 0)
    motion = res.program.op <= MOVEL
    motion[-1] = False
    assert np.all(res.report.status[motion] == IK_OK)
    assert cell.robot.within_limits(res.program.q_rad).all()


def test_a_split_move_does_not_stop_at_its_new_rows() -> None:
    cell = Cell.builtin("kr6r700")
    res = plan_gcode(long_lines(1), cell, PlanOptions(linear_tol_mm=TOL_MM))
    loose = plan_gcode(long_lines(1), cell, PlanOptions(linear_tol_mm=10.0))
    # the new rows carry their move's zone, or a small one where it is fine: the cycle time stays the same
    assert res.estimate_s == pytest.approx(loose.estimate_s, rel=0.02)


def test_moves_across_chunk_boundaries_are_split_too() -> None:
    cell = Cell.builtin("kr6r700")
    text = long_lines(layers=400)                   # ~2,800 rows: chunks of 1,000 cut its long lines
    whole = plan_gcode(text, cell, PlanOptions(linear_tol_mm=TOL_MM))
    chunked = plan_gcode(text, cell, PlanOptions(linear_tol_mm=TOL_MM, ik_block_rows=1000))
    assert len(chunked.program) == len(whole.program)
    assert max(sag_mm(chunked.program, cell.robot, 0.5)) <= TOL_MM
    np.testing.assert_allclose(chunked.program.xyz_mm, whole.program.xyz_mm, atol=1e-9)


def test_the_bound_holds_against_the_measured_sag() -> None:
    """The bound that spares short moves the measurement never lies below the sag (random moves)."""
    rng = np.random.default_rng(7)
    for name in ("kr6r700", "ur10", "panda"):
        robot = Cell.builtin(name).robot
        lo, hi = robot.lower_rad, robot.upper_rad
        q0 = rng.uniform(np.maximum(lo, -3), np.minimum(hi, 3), (4000, robot.nq))
        q1 = np.clip(q0 + rng.normal(0, 0.05, q0.shape), lo, hi)
        chord = 0.5 * (robot.fk(q0)[:, :3, 3] + robot.fk(q1)[:, :3, 3])
        sag = np.linalg.norm(robot.fk(0.5 * (q0 + q1))[:, :3, 3] - chord, axis=1)
        assert np.all(sag_bound_mm(q1 - q0, reach_bound_mm(robot)) >= sag - 1e-9)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), 11.0])
def test_a_bad_tolerance_is_refused(bad: float) -> None:
    with pytest.raises(ValidationError, match="linear_tol_mm"):
        PlanOptions(linear_tol_mm=bad)


@pytest.mark.parametrize("name", ["irb140", "kr6r700", "ur5", "ur10", "panda"])
def test_the_tcp_positions_measured_are_the_forward_kinematics(name: str) -> None:
    """The sag is measured with ``tcp_xyz_mm`` (an OPW arm's own point formula, else the chain walked back
    from the TCP, else the pose's position)."""
    robot = Cell.builtin(name).robot
    q = np.random.default_rng(3).uniform(np.maximum(robot.lower_rad, -3), np.minimum(robot.upper_rad, 3),
                                         (2000, robot.nq))
    np.testing.assert_allclose(robot.tcp_xyz_mm(q), robot.fk(q)[:, :3, 3], atol=1e-9)
    if robot.closed_form is None or robot.closed_form.family != "opw":
        assert isinstance(robot.chain_point, ChainPoint)          # UR and Panda: the walk, not the pose


def test_a_chain_it_cannot_walk_is_left_to_the_poses() -> None:
    """A joint about an axis that is not x, y or z of its frame: no walk (the same chain rebuilt without the
    tilt has one)."""
    robot = Cell.builtin("ur5").robot
    model = robot.pin_model

    def rebuilt(tilt: bool) -> pin.Model:
        built = pin.Model()
        for j in range(1, model.njoints):
            joint = pin.JointModelRevoluteUnaligned(np.array([0.0, 0.6, 0.8])) if tilt and j == 3 else model.joints[j]
            built.addJoint(j - 1, joint, model.jointPlacements[j], model.names[j])
        f = model.frames[robot.tcp_frame_id]
        built.addFrame(pin.Frame("tcp", built.njoints - 1, f.placement, pin.FrameType.OP_FRAME))
        return built

    plain, tilted = rebuilt(False), rebuilt(True)
    assert ChainPoint.of(plain, plain.getFrameId("tcp")) is not None
    assert ChainPoint.of(tilted, tilted.getFrameId("tcp")) is None


def test_fabric_cli_plan_takes_the_tolerance(session, settings, tmp_path) -> None:
    """``fabric-cli plan --linear-tol`` reaches the planner (PlanRequest version 5): a tighter tolerance, more
    pieces, and the exported joints stay within it; a tolerance out of range is refused before any work."""
    cell = Cell.builtin("kr6r700")
    gcode = tmp_path / "lines.gcode"
    gcode.write_text(long_lines())
    planner = PlannerService(session, settings.cell, cell, data_dir=tmp_path / "planner")
    planner.start()
    args = replace(settings, mode="client").to_args()
    try:
        targets = {}
        for tol in ("0.1", "0.02"):
            out = tmp_path / f"p{tol}.csv"
            r = subprocess.run([sys.executable, "-m", "fabric.cli.main", "plan", str(gcode), "--linear-tol", tol,
                                "--csv", str(out), "--json", *args], capture_output=True, text=True, timeout=120)
            assert r.returncode == 0, r.stderr
            targets[tol] = json.loads(r.stdout)["summary"]["targets"]
            data = np.genfromtxt(out, delimiter=",", names=True)
            prog_q = np.radians(np.stack([data[f"q{j}_deg"] for j in range(1, 7)], axis=1))
            xyz = np.stack([data["x_mm"], data["y_mm"], data["z_mm"]], axis=1)
            lin = np.flatnonzero(np.arange(len(data)) > 1)          # after the approach's joint move
            mid = cell.robot.tcp_xyz_mm(0.5 * (prog_q[lin] + prog_q[lin - 1]))
            w = cell.wobj_T()
            line = 0.5 * (xyz[lin] + xyz[lin - 1]) @ w[:3, :3].T + w[:3, 3]
            # the CSV rounds joints to 1e-5 deg (~0.0001 mm at this reach)
            assert np.linalg.norm(mid - line, axis=1)[:-1].max() <= float(tol) + 1e-3
        assert targets["0.02"] > targets["0.1"]
        bad = subprocess.run([sys.executable, "-m", "fabric.cli.main", "plan", str(gcode), "--linear-tol", "0",
                              *args], capture_output=True, text=True, timeout=60)
        assert bad.returncode != 0 and "linear_tol_mm" in bad.stderr
    finally:
        planner.close()


def test_new_rows_are_spread_as_a_repeat_would() -> None:
    """``_spread`` copies stretches of rows between the split moves: the same as ``np.repeat`` of every row,
    for split moves at the first and the last row, next to each other, and none."""
    rng = np.random.default_rng(0)
    for n in (1, 2, 7, 500):
        for _ in range(40):
            rows = np.sort(rng.choice(n, rng.integers(0, n + 1), replace=False))
            pieces = rng.integers(2, 5, len(rows))
            counts = np.ones(n, np.int64)
            counts[rows] = pieces
            end = np.cumsum(counts) - 1
            for col in (rng.normal(size=n), rng.normal(size=(n, 7)), rng.integers(0, 9, n).astype(np.uint8)):
                got = _spread(col, rows, pieces - 1, end)
                assert got.dtype == col.dtype
                np.testing.assert_array_equal(got, np.repeat(col, counts, axis=0))
