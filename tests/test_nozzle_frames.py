"""Nozzle frame quaternions: the straight-down fast path gives what Shepperd's method gives on every row."""
from __future__ import annotations

import numpy as np

from fabric.robot import frames
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
    # the sign rule of a zero w: the largest of x, y positive (z is zero)
    zero_w = q[:, 0] == 0.0
    assert zero_w.all()
    big = np.where(np.abs(q[:, 1]) >= np.abs(q[:, 2]), q[:, 1], q[:, 2])
    assert np.all(big >= 0.0)


def test_down_and_general_paths_agree_bitwise():
    """The fast path is the general rule with |z| = 0 left out: the same bits as the general branch."""
    fr, theta = _frames(np.array([0.0, 0.0, -1.0]), 3000, 2)
    fast = fr.quats(theta)
    fr.const = False                         # the general path over the same frames (Shepperd's quaternion of R0)
    fr.z0 = np.repeat(fr.z0, fr.x0.shape[1], axis=1)
    general = fr.quats(theta)
    assert np.allclose(fast, general, atol=1e-12)
    assert np.array_equal(np.sign(fast[:, 1:3]) != 0, np.sign(general[:, 1:3]) != 0)


def test_tilted_nozzle_keeps_the_general_rule():
    fr, theta = _frames(np.array([0.3, -0.2, -0.9]), 500, 3)
    assert np.allclose(fr.quats(theta), _shepperd(fr, theta), atol=1e-12)
