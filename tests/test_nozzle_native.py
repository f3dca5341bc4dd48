"""The nozzle frames, the IK's flange columns and the TCP quaternions in C (fabric/native/nozzle.c) against
numpy's, for one nozzle axis and an axis per row, a reference parallel to the axis (the fallbacks), one rotation
and a rotation per row.

Within stated ULPs, not to the bit: numpy's AVX-512 kernels (X86_V4) round ``atan2``, sine and cosine otherwise
than libm, and put unit quaternions 1-2 ULPs of 1 away from C's (seen on a Xeon with AVX-512 FP16); with older
kernels they are the same bits. The joints and statuses a path solves to are the same either way.
"""
from __future__ import annotations

import numpy as np
import pytest

from fabric import native
from fabric.robot import nozzle_native
from fabric.robot.cell import Cell
from fabric.robot.frames import QUAT_SIGN_TOL
from fabric.robot.nozzle_frames import NozzleFrames, unit_axes
from fabric.robot.path_ik import solve_path

from support.numeric import assert_ulps

pytestmark = pytest.mark.skipif(native.library("nozzle") is None, reason="no C compiler: numpy's path only")

FRAME_ULPS = 2          # unit vectors: projections, norms and cross products, no transcendental call
QUAT_ULPS = 8           # unit quaternions: atan2, cos and sin of numpy's kernels or libm's (seen: 2)
JOINT_ULPS = 64         # joints (of pi) solved from frames that differ so (seen: 0)


def _frames(z0: np.ndarray, xr: np.ndarray, use_native: bool) -> NozzleFrames:
    NozzleFrames.use_native = use_native
    try:
        return NozzleFrames(z0, xr.copy())
    finally:
        NozzleFrames.use_native = True


@pytest.mark.parametrize("per_row", [False, True])
def test_frames_and_quaternions_are_numpys(per_row: bool) -> None:
    rng = np.random.default_rng(3)
    n = 5000
    z0 = unit_axes(rng.normal(size=(n, 3)) if per_row else np.array([0.2, -0.1, -1.0]), n)
    xr = rng.normal(size=(3, n))
    xr[:, :50] = z0[:, :50] if per_row else z0                  # parallel to the axis: the fallbacks
    xr[:, 50:60] = 0.0
    a, b = _frames(z0, xr, True), _frames(z0, xr, False)
    assert_ulps(a.x0, b.x0, FRAME_ULPS, scale=1.0, what="x0")
    assert_ulps(a.y0, b.y0, FRAME_ULPS, scale=1.0, what="y0")
    if not per_row:                                              # the quaternions of one axis are in C
        for theta in (np.radians(30.0), rng.uniform(-np.pi, np.pi, n), np.array([np.pi, -np.pi] * (n // 2))):
            NozzleFrames.use_native = False
            try:
                want = b.quats(theta)
            finally:
                NozzleFrames.use_native = True
            got = a.quats(theta)
            assert_ulps(got, want, QUAT_ULPS, scale=1.0, what="quaternions")
            assert np.all(want[:, 0] >= -QUAT_SIGN_TOL) and np.all(got[:, 0] >= -QUAT_SIGN_TOL)


def test_the_flange_columns_check_their_rows() -> None:
    z0 = unit_axes(np.array([0.0, 0.0, -1.0]), 4)
    with pytest.raises(ValueError, match="rotation"):
        nozzle_native.flange_cols(np.zeros((3, 4)), np.zeros((3, 4)), np.zeros((3, 4)), z0, np.ones(3), np.ones(3),
                                  np.eye(4))


@pytest.mark.parametrize("name", ["irb140", "ur5", "panda"])
def test_a_path_solved_with_the_c_frames_is_numpys(name: str) -> None:
    """solve_path end to end (frames, flange columns at the chosen rotations, quaternions) both ways."""
    cell = Cell.builtin(name)
    rng = np.random.default_rng(8)
    n = 3000
    t = np.linspace(0.0, 1.0, n)
    plate = cell.wobj_T()
    xyz = (plate[:3, :3] @ np.stack([80.0 + 60.0 * t, 60.0 + 40.0 * np.sin(6.0 * t), 5.0 + rng.uniform(0, 1, n)])
           ).T + plate[:3, 3]
    axis = plate[:3, :3] @ np.array([0.0, 0.0, -1.0])
    out = []
    for use_native in (True, False):
        NozzleFrames.use_native = use_native
        try:
            out.append(solve_path(cell.robot, xyz, axis, np.asarray(cell.home_q_rad, dtype=float)))
        finally:
            NozzleFrames.use_native = True
    a, b = out
    np.testing.assert_array_equal(a.status, b.status)
    np.testing.assert_array_equal(a.rot_deg, b.rot_deg)
    assert_ulps(a.q_rad, b.q_rad, JOINT_ULPS, scale=np.pi, what="joints")
    assert_ulps(a.quat_wxyz, b.quat_wxyz, QUAT_ULPS, scale=1.0, what="quaternions")
    assert a.feasible_r > 0.9
