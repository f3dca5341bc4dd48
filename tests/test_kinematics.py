"""Closed-form IRB 140 IK (all branches, continuity, status codes) and the free-rotation path IK."""
from __future__ import annotations

import time

import numpy as np
import pytest

from fabric.robot import frames
from fabric.robot.cell import Cell
from fabric.robot.closed_form import ClosedFormIK
from fabric.robot.kinematics import (
    IK_JOINT_LIMIT,
    IK_JUMP,
    IK_OK,
    IK_OUT_OF_REACH,
    IK_REASONS,
    IK_SINGULAR,
    IRB140_ARM,
    SphericalWristArm,
)
from fabric.robot.model import IRB140_URDF, RobotModel
from fabric.robot.path_ik import joint_jumps, solve_path


@pytest.fixture(scope="module")
def robot() -> RobotModel:
    return RobotModel.from_urdf(IRB140_URDF)


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


def _wrapped(a: np.ndarray) -> np.ndarray:
    return a - 2 * np.pi * np.rint(a / (2 * np.pi))


@pytest.mark.parametrize("arm", [IRB140_ARM, SphericalWristArm(400.0, 150.0, 600.0, 120.0, 720.0, 85.0)])
def test_every_branch_round_trips(arm: SphericalWristArm) -> None:
    rng = np.random.default_rng(7)
    lo = np.radians([-180, -90, -230, -200, -115, -400])
    q = rng.uniform(lo, -lo * np.array([1, 110 / 90, 50 / 230, 1, 1, 1]), (5000, 6))
    T = arm.fk_flange(q)
    qb, reach, _ = arm.ik_branches(T)
    assert np.all(reach.sum(axis=1) >= 2)      # at least the producing shoulder/elbow, both wrists
    for b in range(8):
        Tb = arm.fk_flange(qb[:, b])[reach[:, b]]
        np.testing.assert_allclose(Tb[:, :3, 3], T[reach[:, b], :3, 3], atol=1e-9)      # mm
        np.testing.assert_allclose(Tb[:, :3, :3], T[reach[:, b], :3, :3], atol=1e-12)
    # the configuration that produced each pose is one of the 8
    assert np.all(np.min(np.max(np.abs(_wrapped(qb - q[:, None, :])), axis=2), axis=1) < 1e-9)


def test_ik_round_trip_within_limits(robot: RobotModel) -> None:
    rng = np.random.default_rng(8)
    q = rng.uniform(robot.lower_rad, robot.upper_rad, (20_000, 6))
    T = robot.fk(q)
    qs, st = robot.ik(T, q[0])
    assert set(np.unique(st)) <= {IK_OK, IK_SINGULAR}
    np.testing.assert_allclose(robot.fk(qs)[:, :3, 3], T[:, :3, 3], atol=1e-9)
    np.testing.assert_allclose(robot.fk(qs)[:, :3, :3], T[:, :3, :3], atol=1e-12)
    assert robot.within_limits(qs).all()


def _smooth_path(n: int) -> np.ndarray:
    s = np.linspace(0.0, 1.0, n)
    return np.column_stack([
        np.radians(170) * np.sin(2 * np.pi * s),          # A1 sweeps almost the whole range
        np.radians(20) + 0.4 * np.sin(3 * np.pi * s),
        np.radians(-30) + 0.5 * np.cos(2 * np.pi * s),
        np.radians(150) * np.sin(4 * np.pi * s),
        np.radians(60) * np.cos(3 * np.pi * s) + 1e-3,   # the wrist passes near q5 = 0 (flip)
        np.radians(-350) + np.radians(700) * s,          # A6 winds past +-180
    ])


def test_continuity_follows_the_path_through_wrist_flips_and_wind_up(robot: RobotModel) -> None:
    q = _smooth_path(20_000)
    qs, st = robot.ik(robot.fk(q), q[0])
    assert np.all((st == IK_OK) | (st == IK_SINGULAR))
    np.testing.assert_allclose(qs, q, atol=1e-8)          # same configuration and turn all along
    assert np.degrees(np.abs(np.diff(qs, axis=0)).max()) < 1.0


def test_tracking_mode_equals_the_full_8_branch_rule(robot: RobotModel) -> None:
    rng = np.random.default_rng(9)
    smooth = _smooth_path(3000)
    scattered = rng.uniform(robot.lower_rad, robot.upper_rad, (3000, 6))
    T = robot.fk(np.concatenate([smooth, scattered, smooth[::-1]]))
    fast = ClosedFormIK(IRB140_ARM, robot.lower_rad, robot.upper_rad, robot.tool_T)
    full = ClosedFormIK(IRB140_ARM, robot.lower_rad, robot.upper_rad, robot.tool_T)
    full.tracking = False
    qa, sa = fast.solve(T, smooth[0])
    qb, sb = full.solve(T, smooth[0])
    np.testing.assert_array_equal(sa, sb)
    np.testing.assert_allclose(qa, qb, atol=1e-12)


def test_unreachable_rows_are_out_of_reach_and_hold_the_joints(robot: RobotModel) -> None:
    q0 = np.radians([0, 10, -10, 0, 60, 0])
    T = np.repeat(robot.fk(q0)[None], 3, axis=0)
    T[1, :3, 3] = [2000.0, 0.0, 500.0]
    qs, st = robot.ik(T, q0)
    assert st.tolist() == [IK_OK, IK_OUT_OF_REACH, IK_OK]
    np.testing.assert_allclose(qs[1], qs[0])
    assert IK_REASONS[IK_OUT_OF_REACH] == "out of reach"


def test_targets_beyond_the_limits_are_joint_limit() -> None:
    narrow = RobotModel.from_urdf(IRB140_URDF).with_limits(
        lower_rad=np.radians([-180, -20, -60, -200, -30, -400]), upper_rad=np.radians([180, 60, 30, 200, 30, 400]))
    q = np.radians([0, 20, -10, 0, 60, 0])
    qs, st = narrow.ik(narrow.fk(q), np.zeros(6))
    assert st[0] == IK_JOINT_LIMIT
    assert not narrow.within_limits(qs)[0]
    np.testing.assert_allclose(narrow.fk(qs[0]), narrow.fk(q), atol=1e-9)   # still the nearest exact solution


def test_singular_poses_are_flagged(robot: RobotModel) -> None:
    q3_shoulder = -np.degrees(np.arccos(-70.0 / 380.0))                 # wrist centre on the A1 axis
    qs = np.radians([[0, 0, 0, 0, 0, 0],                                 # wrist: q5 = 0
                     [0, 30, -90, 0, 40, 0],                             # elbow stretched
                     [20, 0, q3_shoulder, 10, 40, 0],                    # shoulder
                     [0, 10, -10, 0, 60, 0]])                            # regular
    for i, q in enumerate(qs):
        sol, st = robot.ik(robot.fk(q), q)
        np.testing.assert_allclose(robot.fk(sol[0]), robot.fk(q), atol=1e-9)
        assert st[0] == (IK_OK if i == len(qs) - 1 else IK_SINGULAR), np.degrees(q)


def test_exact_wrist_singularity_holds_a4(robot: RobotModel) -> None:
    qa = np.array([0.1, 0.3, -0.2, 0.7, 0.3, 0.2])
    qb = np.array([0.1, 0.3, -0.2, 0.0, 0.0, 0.9])                       # q5 = 0: only q4 + q6 matters
    qs, st = robot.ik(robot.fk(np.stack([qa, qb])), qa)
    assert st[1] == IK_SINGULAR
    assert qs[1, 3] == pytest.approx(0.7)                                 # A4 held
    assert qs[1, 3] + qs[1, 5] == pytest.approx(0.9)
    np.testing.assert_allclose(robot.fk(qs[1]), robot.fk(qb), atol=1e-9)


def test_throughput_on_a_toolpath(robot: RobotModel) -> None:
    q = _smooth_path(200_000)
    T = robot.fk(q)
    t0 = time.perf_counter()
    _q, st = robot.ik(T, q[0])
    dt = time.perf_counter() - t0
    assert np.all(st != IK_OUT_OF_REACH)
    assert dt < 4.0, f"{len(q) / dt:,.0f} targets/s"    # ~1e6 targets/s on a quiet core


def _plate_raster(cell: Cell, n_side: int, z_mm: float) -> np.ndarray:
    u = np.linspace(0.0, cell.plate_size_mm[0], n_side)
    X, Y = np.meshgrid(u, u)
    X[1::2] = X[1::2, ::-1]                                              # serpentine
    pts = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, z_mm)])
    W = cell.wobj_T()
    return pts @ W[:3, :3].T + W[:3, 3]


def test_solve_path_on_the_plate_raster(cell: Cell) -> None:
    xyz = _plate_raster(cell, 101, 0.3)
    res = solve_path(cell.robot, xyz, np.array([0.0, 0.0, -1.0]), cell.home_q_rad)
    assert res.feasible_r == 1.0 and np.all(res.status == IK_OK) and res.strategy == "constant"
    assert np.degrees(np.abs(np.diff(res.q_rad, axis=0)).max()) < 3.0     # continuous
    T = cell.robot.fk(res.q_rad)
    np.testing.assert_allclose(T[:, :3, 3], xyz, atol=1e-9)
    np.testing.assert_allclose(T[:, :3, 2], np.tile([0.0, 0.0, -1.0], (len(xyz), 1)), atol=1e-12)
    np.testing.assert_allclose(frames.R_from_quat(res.quat_wxyz), T[:, :3, :3], atol=1e-9)
    assert np.min(np.abs(np.sin(res.q_rad[:, 4]))) > np.sin(np.radians(15))   # clear of the wrist singularity


def test_solve_path_changes_rotation_when_no_constant_one_fits(cell: Cell) -> None:
    # A6 narrowed to +-8 deg with theta measured from the base x axis: A6 must follow A1 (+-15 deg over
    # the plate), so no constant rotation fits and the Viterbi pass must turn theta along the path.
    r = RobotModel.from_urdf(IRB140_URDF)
    r.with_limits(lower_rad=np.radians([-180, -90, -230, -200, -115, -8]),
                  upper_rad=np.radians([180, 110, 50, 200, 115, 8]))
    xyz = _plate_raster(cell, 41, 0.3)
    res = solve_path(r, xyz, [0.0, 0.0, -1.0], np.radians([0, 0, 0, 0, 90, 0]), rot_step_deg=5.0,
                     x_ref=np.array([-1.0, 0.0, 0.0]))
    assert res.strategy == "viterbi"
    assert np.all(res.status == IK_OK)
    assert np.ptp(res.rot_deg) >= 20.0
    assert np.degrees(np.abs(np.diff(res.q_rad, axis=0)).max()) < 10.0
    np.testing.assert_allclose(r.fk(res.q_rad)[:, :3, 3], xyz, atol=1e-9)


def test_joint_jumps_catch_flips_but_not_long_moves(robot: RobotModel, cell: Cell) -> None:
    q = _smooth_path(400)[:200]
    T = robot.fk(q)
    flipped = q.copy()
    flipped[100:, 3] += np.pi
    flipped[100:, 4] *= -1.0
    flipped[100:, 5] += np.pi                                            # same poses, other wrist branch
    np.testing.assert_allclose(robot.fk(flipped), T, atol=1e-9)
    assert np.flatnonzero(joint_jumps(robot, flipped, T)).tolist() == [100]
    assert not joint_jumps(robot, q, T).any()
    # a 350 mm travel move across the plate diagonal is continuous
    xyz = _plate_raster(cell, 2, 0.3)[[0, 3]]
    res = solve_path(cell.robot, xyz, [0.0, 0.0, -1.0], cell.home_q_rad)
    assert res.status.tolist() == [IK_OK, IK_OK] and IK_JUMP not in res.status
