"""The closed-form solver's tracking step in C gives numpy's joints and statuses on OPW and UR arms."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fabric.robot.cell import Cell
from fabric.robot.closed_form import ClosedFormIK
from fabric.robot.kinematics import IK_OK, pose_cols
from fabric.robot.opw import OPWArm

pytestmark = pytest.mark.skipif(Cell.builtin("irb140").robot.closed_form._tracker is None,
                                reason="the C tracking step is not built here")


def walk(cf: ClosedFormIK, n: int, seed: int) -> np.ndarray:
    """A random joint walk (small steps, a few large ones), inside the limits by a margin (no row on a limit,
    where the two paths may round a joint to either side)."""
    rng = np.random.default_rng(seed)
    lo, hi = cf.lower_rad, cf.upper_rad
    lo, hi = np.maximum(lo, -np.pi) + 0.05, np.minimum(hi, np.pi) - 0.05
    steps = rng.normal(0.0, 0.01, (n, cf.nq))
    steps[rng.random(n) < 0.003] *= 80.0                   # jumps: the tracking fails and the full method runs
    q = 0.5 * (lo + hi) + np.cumsum(steps, axis=0)
    span = hi - lo
    q = lo + np.abs((q - lo + span) % (2 * span) - span)    # reflected into [lo, hi]
    return q


def both(cf: ClosedFormIK, C: np.ndarray, seed_q: np.ndarray) -> tuple[tuple, tuple]:
    tracker = cf._tracker
    got = cf.ik_cols(C, seed_q)
    cf._tracker = None
    try:
        want = cf.ik_cols(C, seed_q)
    finally:
        cf._tracker = tracker
    return got, want


def check(cf: ClosedFormIK, q: np.ndarray) -> None:
    C = pose_cols(cf.fk_flange(q), cf._end_inv)
    (qa, sa), (qb, sb) = both(cf, C, q[0])
    np.testing.assert_array_equal(sa, sb)
    np.testing.assert_allclose(qa, qb, rtol=0, atol=1e-9)
    assert np.mean(sa == IK_OK) > 0.5                        # a walk mostly through valid rows, not refusals
    ok = sa == IK_OK
    np.testing.assert_allclose(cf.fk_flange(qa[ok])[:, :3, 3], cf.fk_flange(q[ok])[:, :3, 3], atol=1e-6)


@pytest.mark.parametrize("name", ["irb140", "kr6r700", "ur5", "ur10"])
def test_same_joints_as_numpy_on_a_walk(name: str) -> None:
    cf = Cell.builtin(name).robot.closed_form
    assert cf._tracker is not None
    check(cf, walk(cf, 20000, seed=len(name)))


def test_an_arm_with_a_shoulder_offset_a_placed_base_and_a_reversed_joint() -> None:
    """The C step's base frame, shoulder offset b (two gaps) and joint signs, on an OPW arm none of the
    built-in cells has."""
    ref = Cell.builtin("irb140").robot.closed_form
    p = ref.arm.params
    params = dataclasses.replace(p, b_mm=40.0, signs=(1.0, -1.0, 1.0, 1.0, -1.0, 1.0), base_T=_placed_base())
    cf = ClosedFormIK(OPWArm(params), ref.lower_rad, ref.upper_rad, ref.tool_T)
    assert cf._tracker is not None and cf.arm._base is not None
    check(cf, walk(cf, 20000, seed=7))


def test_a_path_through_a_wrist_flip_takes_the_full_method_and_agrees() -> None:
    """Targets that cross the wrist singularity (A5 through 0): tracking stops there, the full method picks
    the branch, both ways alike."""
    cf = Cell.builtin("kr6r700").robot.closed_form
    n = 4000
    q = np.tile(0.5 * (np.maximum(cf.lower_rad, -np.pi) + np.minimum(cf.upper_rad, np.pi)), (n, 1))
    q[:, 4] = np.linspace(-0.6, 0.6, n)
    q[:, 3] = np.linspace(-0.3, 0.3, n)
    C = pose_cols(cf.fk_flange(q), cf._end_inv)
    (qa, sa), (qb, sb) = both(cf, C, q[0])
    np.testing.assert_array_equal(sa, sb)
    np.testing.assert_allclose(qa, qb, rtol=0, atol=1e-9)


def _placed_base() -> np.ndarray:
    """Axis 1 turned 0.5 rad about z and moved off the URDF's origin."""
    c, s = np.cos(0.5), np.sin(0.5)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = [30.0, -20.0, 100.0]
    return T
