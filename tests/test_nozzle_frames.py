"""Nozzle frame quaternions: what Shepperd's method gives on every row, straight down (w = 0 on every row, where
the sign rule decides) and tilted."""
from __future__ import annotations

import numpy as np

from fabric.robot import frames
from fabric.robot.frames import QUAT_SIGN_TOL
from fabric.robot.nozzle_frames import NozzleFrames, unit_axes


def _frames(z_axis: np.ndarray, n: int, seed: int) -> tuple[NozzleFrames, np.ndarray]:
    rng = np.random.default_rng(seed)
    p = rng.uniform(-400.0, 400.0, (3, n))
    p[:, :3] = [[0.0, 5.0, -5.0], [7.0, 0.0, 0.0], [1.0, 1.0, 1.0]]      # on the axes: x or y zero
    xr = np.stack([-p[0], -p[1], np.zeros(n)])
    return NozzleFrames(unit_axes(np.broadcast_to(z_axis, (n, 3)), n), xr), rng.uniform(-np.pi, np.pi, n)


def _shepperd(fr: NozzleFrames, theta: np.ndarray) -> np.ndarray:
    """Each row's rotation matrix ``R0 Rz(theta)`` through ``frames.quat_from_R``, row by row (the reference)."""
    x0, y0, z0 = fr.cols(slice(None))
    c, s = np.cos(theta), np.sin(theta)
    R = np.stack([(c * x0 + s * y0).T, (c * y0 - s * x0).T, np.broadcast_to(z0, x0.shape).T], axis=-1)
    return frames.quat_from_R(R)


def test_down_nozzle_quaternions_match_shepperd():
    fr, theta = _frames(np.array([0.0, 0.0, -1.0]), 2000, 1)
    q = fr.quats(theta)
    ref = _shepperd(fr, theta)
    assert np.all(q[:, 0] >= 0.0)
    assert np.allclose(q, ref, atol=1e-12)
    # the sign rule of a zero w (frames.quat_sign): the first of x, y, z that is not zero but for rounding is
    # positive (z is zero), whatever sign the rounding gave w
    zero_w = np.abs(q[:, 0]) <= QUAT_SIGN_TOL
    assert zero_w.all()
    lead = np.where(np.abs(q[:, 1]) > QUAT_SIGN_TOL, q[:, 1], q[:, 2])
    assert np.all(lead > 0.0)


def test_tilted_nozzle_quaternions_match_shepperd():
    fr, theta = _frames(np.array([0.3, -0.2, -0.9]), 500, 3)
    assert np.allclose(fr.quats(theta), _shepperd(fr, theta), atol=1e-12)
