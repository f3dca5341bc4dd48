"""Motion timing: trapezoids, junctions, vectorised look-ahead, joint caps, Ruckig joint moves, sampling."""
from __future__ import annotations

import numpy as np
import pytest

from fabric.motion.program import MOVEJ, MOVEL, WAIT, Program
from fabric.motion.timing import StartState, stop_timeline, time_program
from fabric.motion.validate import validate_program
from fabric.robot.frames import make_T
from fabric.robot.model import IRB140_URDF, RobotModel
from fabric.wire.errors import UnreachableError, ValidationError

A = 2000.0


class PointRobot:
    """Joints 0..2 are the TCP position in metres (so joint caps never bite), fk = translation."""

    lower_rad = np.full(6, -1e3)
    upper_rad = np.full(6, 1e3)
    vel_limit_rad_s = np.full(6, 3.0)
    acc_limit_rad_s2 = np.full(6, 12.0)
    jerk_limit_rad_s3 = np.full(6, 120.0)

    def fk(self, q: np.ndarray) -> np.ndarray:
        q = np.atleast_2d(q)
        return make_T(np.broadcast_to(np.eye(3), (len(q), 3, 3)), q[:, :3] * 1000.0)


def line_program(pts: np.ndarray, speed: float | np.ndarray = 50.0, zone: float | np.ndarray = 0.0) -> Program:
    p = Program.empty(len(pts))
    p.op[:] = MOVEL
    p.xyz_mm[:] = pts
    p.q_rad[:, :3] = pts / 1000.0
    p.speed_mm_s[:] = speed
    p.zone_mm[:] = zone
    return p


@pytest.fixture(scope="module")
def irb() -> RobotModel:
    return RobotModel.from_urdf(IRB140_URDF)


def test_single_move_is_an_exact_trapezoid() -> None:
    tl = time_program(line_program(np.array([[0, 0, 0], [100.0, 0, 0]]), speed=50.0), PointRobot())
    # accelerate 0->50 over 0.025 s, cruise, decelerate: L/v + v/a
    assert tl.total_s == pytest.approx(100.0 / 50.0 + 50.0 / A, rel=1e-12)
    assert tl.vc_mm_s[1] == pytest.approx(50.0)
    short = time_program(line_program(np.array([[0, 0, 0], [0.5, 0, 0]]), speed=100.0), PointRobot())
    assert short.total_s == pytest.approx(2.0 * np.sqrt(0.5 / A), rel=1e-12)   # triangle, never cruises
    assert short.vc_mm_s[1] == pytest.approx(np.sqrt(A * 0.5))


def test_junction_speed_follows_zone_and_angle() -> None:
    pts = np.array([[0, 0, 0], [50.0, 0, 0], [50.0, 50.0, 0], [100.0, 50.0, 0], [150.0, 50.0, 0]])
    zone = 0.05
    tl = time_program(line_program(pts, speed=100.0, zone=zone), PointRobot())
    s = np.sin(np.pi / 4)                                   # 90 deg corner
    assert tl.v1_mm_s[1] == pytest.approx(np.sqrt(A * zone * s / (1 - s)), rel=1e-9)
    assert tl.v0_mm_s[2] == tl.v1_mm_s[1]
    assert tl.v1_mm_s[3] == pytest.approx(100.0)            # collinear: no slowdown
    fine = time_program(line_program(pts, speed=100.0, zone=0.0), PointRobot())
    assert fine.v1_mm_s[1] == 0.0 and fine.total_s > tl.total_s


def _reference_passes(L: np.ndarray, cap: np.ndarray, J: np.ndarray) -> np.ndarray:
    """Textbook sequential backward/forward passes (squared speeds at segment entries)."""
    n = len(L)
    w = np.zeros(n)
    nxt = 0.0
    for i in range(n - 1, -1, -1):
        w[i] = min(J[i], cap[i] ** 2, nxt + 2 * A * L[i])
        nxt = w[i]
    u = np.zeros(n)
    prev = 0.0
    for i in range(n):
        u[i] = min(w[i], prev) if i else 0.0
        prev = u[i] + 2 * A * L[i]
    return u


def test_vectorised_lookahead_matches_sequential_reference() -> None:
    rng = np.random.default_rng(3)
    n = 3000
    pts = np.cumsum(rng.normal(0, 2.0, size=(n, 3)), axis=0)
    speed = rng.uniform(20, 120, n)
    zone = np.where(rng.random(n) < 0.1, 0.0, rng.uniform(0.01, 0.5, n))
    tl = time_program(line_program(pts, speed=speed, zone=zone), PointRobot())
    d = np.diff(pts, axis=0)
    L = np.linalg.norm(d, axis=1)
    u = d / L[:, None]
    sin_h = np.sqrt(np.clip(0.5 * (1 + np.sum(u[:-1] * u[1:], axis=1)), 0, 1))
    J = np.concatenate([[0.0], A * zone[1:-1] * sin_h / np.maximum(1 - sin_h, 1e-12)])
    cap = speed[1:]
    J[1:] = np.minimum(J[1:], np.minimum(cap[:-1], cap[1:]) ** 2)
    ref = _reference_passes(L, cap, J)
    np.testing.assert_allclose(tl.v0_mm_s[1:] ** 2, ref, rtol=1e-7, atol=1e-6)
    # every trapezoid is feasible and junctions are continuous
    assert np.all(np.abs(tl.v1_mm_s[1:] ** 2 - tl.v0_mm_s[1:] ** 2) <= 2 * A * L + 1e-6)
    np.testing.assert_array_equal(tl.v1_mm_s[1:-1], tl.v0_mm_s[2:])
    np.testing.assert_array_equal(tl.t_start_s[1:], tl.t_end_s[:-1])
    assert tl.total_s == pytest.approx(np.sum(tl.duration_s), rel=1e-12)


def test_sampling_walks_the_path_exactly() -> None:
    pts = np.array([[0, 0, 0], [30.0, 0, 0], [30.0, 20.0, 0]])
    tl = time_program(line_program(pts, speed=40.0, zone=0.2), PointRobot())
    t = np.linspace(0, tl.total_s, 4001)
    b = tl.sample_many(t)
    np.testing.assert_allclose(b.xyz_mm[-1], pts[-1], atol=1e-12)
    travelled = np.sum(np.linalg.norm(np.diff(b.xyz_mm, axis=0), axis=1))
    assert travelled == pytest.approx(50.0, abs=0.02)       # corner cut by the sampling only
    assert np.trapezoid(b.tcp_speed_mm_s, t) == pytest.approx(50.0, rel=1e-5)
    at_row_end = tl.sample(tl.t_end_s[1])
    np.testing.assert_allclose(at_row_end.xyz_mm, pts[1], atol=1e-9)
    assert tl.sample(0.3).row == int(tl.locate(np.array([0.3]))[0])


def test_joint_velocity_caps_slow_a_move_near_the_wrist_singularity(irb: RobotModel) -> None:
    q0 = np.radians([0, 20, 10, 0, 2, 0])                      # A5 = 2 deg: close to the wrist singularity
    T0 = irb.fk(q0[None])[0]
    T = np.repeat(T0[None], 11, axis=0)
    T[:, 1, 3] += np.linspace(-10, 10, 11)                    # 20 mm straight across, orientation fixed
    q, status = irb.ik(T, q0)
    assert np.all(status == 0)
    p = Program.empty(11)
    p.op[:] = MOVEL
    p.q_rad[:] = q
    p.xyz_mm[:] = T[:, :3, 3]
    p.speed_mm_s[:] = 200.0
    p.zone_mm[:] = 1.0
    tl = time_program(p, irb, accel_mm_s2=20000.0)
    assert len(tl.slowed_rows) > 0 and set(tl.slowed_joint.tolist()) <= {3, 5}   # A4 / A6
    dq = np.abs(np.diff(q, axis=0))
    L = np.linalg.norm(np.diff(p.xyz_mm, axis=0), axis=1)
    rate = np.max(dq * tl.vc_mm_s[1:, None] / L[:, None] / irb.vel_limit_rad_s, axis=1)
    assert rate.max() <= 1.0 + 1e-9                            # no joint over its limit at cruise
    assert tl.vc_mm_s[tl.slowed_rows].max() < 200.0
    far = time_program(p, irb, accel_mm_s2=20000.0, speed_r=0.1)
    assert len(far.slowed_rows) == 0                           # slow enough: nothing to report


def test_joint_move_is_ruckig_within_limits(irb: RobotModel) -> None:
    home = np.radians([0, 0, 0, 0, 30, 0])
    target = np.radians([40, 30, -20, 10, 50, -30])
    p = Program.empty(2)
    p.op[:] = MOVEJ
    p.q_rad[0], p.q_rad[1] = home, target
    p.vel_r[:] = 0.5
    tl = time_program(p, irb, start_state=StartState.at_joints(irb, np.eye(4), home))
    tr = tl.joint_traj[1]
    assert tl.duration_s[1] == pytest.approx(tr.duration) and tr.duration > 0
    t = np.linspace(tl.t_start_s[1], tl.t_end_s[1], 2001)
    b = tl.sample_many(t)
    qd = np.abs(np.diff(b.q_rad, axis=0)) / np.diff(t)[:, None]
    assert np.all(qd <= 0.5 * irb.vel_limit_rad_s * 1.001)
    np.testing.assert_allclose(b.q_rad[-1], target, atol=1e-12)
    faster = time_program(p, irb, start_state=StartState.at_joints(irb, np.eye(4), home), speed_r=2.0)
    assert faster.total_s < tl.total_s


def test_reentry_faster_than_new_cap_decelerates() -> None:
    pts = np.array([[0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [40.0, 0, 0]])
    p = line_program(pts, speed=100.0, zone=1.0)
    ss = StartState(p.q_rad[0], pts[0], p.quat_wxyz[0], v_mm_s=100.0)
    tl = time_program(p, PointRobot(), speed_r=0.2, start_row=1, start_state=ss)
    assert tl.v0_mm_s[0] == pytest.approx(100.0)
    L = np.diff(pts, axis=0)[:, 0]
    assert np.all(np.abs(tl.v1_mm_s ** 2 - tl.v0_mm_s ** 2) <= 2 * A * L + 1e-6)
    assert tl.vc_mm_s[-1] == pytest.approx(20.0)


def test_controlled_stop_distance() -> None:
    pts = np.array([[0, 0, 0], [10.0, 0, 0], [10.2, 0, 0], [100.0, 0, 0]])
    tl = time_program(line_program(pts, speed=60.0, zone=1.0), PointRobot())
    t = tl.t_end_s[1] - 0.001                                  # 1 ms before the end of the first move
    smp = tl.sample(t)
    st, row, _s = stop_timeline(tl, t)
    travelled = np.sum(st.len_mm)
    assert travelled == pytest.approx(smp.tcp_speed_mm_s ** 2 / (2 * A), rel=1e-9)
    assert st.total_s == pytest.approx(smp.tcp_speed_mm_s / A, rel=1e-9)
    end = st.sample(st.total_s)
    assert end.tcp_speed_mm_s == pytest.approx(0.0, abs=1e-9)
    assert row >= 2 and end.xyz_mm[0] == pytest.approx(smp.xyz_mm[0] + travelled)


def test_waits_and_validation(irb: RobotModel) -> None:
    p = line_program(np.array([[0, 0, 0], [10.0, 0, 0], [10.0, 0, 0]]))
    p.op[2], p.value[2] = WAIT, 1.5
    tl = time_program(p, PointRobot())
    assert tl.duration_s[2] == 1.5
    bad = line_program(np.array([[0, 0, 0], [10.0, 0, 0]]))
    bad.xyz_mm[1, 2] = np.nan
    with pytest.raises(ValidationError) as e:
        validate_program(bad, PointRobot())
    assert e.value.details["field"] == "xyz_mm" and e.value.details["row"] == 1
    far = Program.empty(2)
    far.vel_r[:] = 1.0
    far.q_rad[1, 4] = np.radians(130)                          # A5 beyond +115 deg
    far.gcode_line[1] = 42
    with pytest.raises(UnreachableError) as e:
        validate_program(far, irb)
    assert e.value.details["joint"] == 4 and e.value.details["gcode_line"] == 42
