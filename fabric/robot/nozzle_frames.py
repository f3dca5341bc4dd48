"""Nozzle frames of a printing path: the orientation of each row at theta = 0, and quaternions at any theta.

Printing fixes only the nozzle axis (TCP +z). The frame ``R0_i`` of row i has
z along the nozzle axis and x along a reference direction projected onto the
plane normal to z; the orientation for a rotation theta about the nozzle is
``R0_i @ Rz(theta)``. Frames are kept as columns (3, N) so that every
operation runs on contiguous rows of N numbers.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fabric.robot import frames, nozzle_native
from fabric.wire.errors import ValidationError

__all__ = ["NozzleFrames", "FrameCols", "unit_axes"]


class FrameCols(NamedTuple):
    """The axes of ``R0`` of some rows as columns: ``x0``, ``y0`` (3, M) and ``z0`` ((3, 1) or (3, M))."""

    x0: np.ndarray
    y0: np.ndarray
    z0: np.ndarray


def unit_axes(z_axis: np.ndarray, n: int) -> np.ndarray:
    """Nozzle axes as unit columns: (3, 1) when one axis serves every row (also a broadcast one), else (3, N)."""
    z = np.asarray(z_axis, dtype=float)
    if z.ndim == 2 and z.shape[1] == 3 and (len(z) == 1 or z.strides[0] == 0):
        z = z[0]                                        # a broadcast (N, 3) of one axis
    z = np.broadcast_to(z, (1 if z.ndim == 1 else n, 3))
    zn = np.linalg.norm(z, axis=1)
    if n and (not np.all(np.isfinite(zn)) or np.any(zn < 1e-9)):
        bad = int(np.argmax(~np.isfinite(zn) | (zn < 1e-9)))
        raise ValidationError(f"z_axis row {bad} is not a direction", field="z_axis", row=bad)
    return np.ascontiguousarray((z / zn[:, None]).T)


class NozzleFrames:
    """The nozzle frames ``R0_i`` (theta = 0) as columns ``x0, y0`` (3, N) and ``z0`` ((3, 1) or (3, N)).

    Built like :func:`fabric.robot.frames.frame_from_z_axis`: ``x_ref`` projected
    onto the plane normal to z (base x, then base y where it is parallel to z),
    ``y = z x x``. Columns keep every operation on contiguous rows of N numbers.
    The frames and the quaternions of one nozzle axis are computed in C where the helper is built
    (:mod:`fabric.robot.nozzle_native`, the same arithmetic), else by numpy.
    """

    use_native = True           # False: numpy's path even where the C helper could answer (reference for tests)

    def __init__(self, z0: np.ndarray, xr: np.ndarray) -> None:
        self.z0 = z0
        self.const = z0.shape[1] == 1
        done = nozzle_native.frames(z0, xr) if self.use_native else None
        if done is not None:
            self.x0, self.y0 = done
            return
        n = xr.shape[1]
        bad = np.zeros(n, dtype=bool)
        for fallback in (None, (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)):
            if fallback is not None:
                xr[:, bad] = np.asarray(fallback)[:, None]
            x = xr - (xr * z0).sum(axis=0) * z0
            nx = np.sqrt((x * x).sum(axis=0))
            bad = nx < 1e-6
            if not bad.any():
                break
        x /= nx
        self.x0 = x
        self.y0 = np.stack([z0[1] * x[2] - z0[2] * x[1],          # z x x
                            z0[2] * x[0] - z0[0] * x[2],
                            z0[0] * x[1] - z0[1] * x[0]])

    def cols(self, rows: slice | np.ndarray) -> FrameCols:
        """``x0, y0, z0`` of some rows (z0 stays (3, 1) when constant)."""
        z0 = self.z0 if self.const else self.z0[:, rows]
        return FrameCols(self.x0[:, rows], self.y0[:, rows], z0)

    def quats(self, theta_rad: np.ndarray) -> np.ndarray:
        """(N, 4) quaternions ``(w, x, y, z)`` (sign: ``frames.quat_sign``) of ``R0_i @ Rz(theta_i)``.

        With one nozzle axis every frame is ``B @ Rz(alpha_i)`` for a fixed ``B``
        (z column the axis), so the quaternion is ``q_B * (cos h, 0, 0, sin h)``
        with ``h = (alpha_i + theta_i) / 2``: no per-row matrix. Otherwise
        Shepperd's method on ``R0`` and the same product with ``h = theta_i / 2``.
        """
        if self.const:
            B = frames.frame_from_z_axis(self.z0[:, 0], np.array([1.0, 0.0, 0.0]))[0]
            qa = frames.quat_from_R(B)
            done = nozzle_native.quats(self.x0, B, qa, theta_rad) if self.use_native else None
            if done is not None:
                return done
            x0 = self.x0                                   # b . x0 term by term, in order (as nozzle.c)
            dy = B[0, 1] * x0[0] + B[1, 1] * x0[1] + B[2, 1] * x0[2]
            dx = B[0, 0] * x0[0] + B[1, 0] * x0[1] + B[2, 0] * x0[2]
            half = 0.5 * (np.arctan2(dy, dx) + theta_rad)
            w1, x1, y1, z1 = qa
        else:
            qa = frames.quat_from_R(np.stack([self.x0.T, self.y0.T, self.z0.T], axis=-1))
            half = 0.5 * np.broadcast_to(theta_rad, self.x0.shape[1:])
            w1, x1, y1, z1 = qa.T
        c, s = np.cos(half), np.sin(half)
        cols = (w1 * c - z1 * s, x1 * c + y1 * s, y1 * c - x1 * s, z1 * c + w1 * s)
        return frames.quat_sign(np.stack(cols, axis=1))
