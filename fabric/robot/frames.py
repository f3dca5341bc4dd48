"""Pose helpers: homogeneous transforms, RPY and quaternions, vectorised over leading axes.

Conventions used everywhere in the fabric:

* poses are 4x4 homogeneous matrices in **millimetres**; stacks are ``(N, 4, 4)``;
* ``rpy_deg`` is the URDF / ROS convention: fixed-axis roll about x, then pitch
  about y, then yaw about z, i.e. ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``. RoboDK's
  ``(x, y, z, rx, ry, rz)`` in Table II is the same matrix for the zero and
  single-axis rotations used there;
* quaternions are ``(w, x, y, z)`` (ABB RAPID order) with the sign :func:`quat_sign` chooses: ``w > 0``, or
  where ``w`` is zero but for rounding (a half turn: a nozzle pointing down), the first of ``x, y, z`` that is
  not is positive. The sign is never chosen by a rounding error's, so every CPU writes the same quaternion.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "rot_x", "rot_y", "rot_z", "rpy_to_R", "R_to_rpy", "make_T", "xyzrpy_to_T", "T_to_xyzrpy",
    "inv_T", "quat_from_R", "R_from_quat", "frame_from_z_axis", "rot_about_z", "nlerp_quat", "quat_sign",
    "QUAT_SIGN_TOL",
]

QUAT_SIGN_TOL = 1e-9      # a quaternion's components this small are rounding noise: they never choose its sign


def _rot(axis: int, angle_rad: np.ndarray | float) -> np.ndarray:
    a = np.asarray(angle_rad, dtype=float)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    return R


def rot_x(angle_rad: np.ndarray | float) -> np.ndarray:
    """Rotation matrix (..., 3, 3) about x by ``angle_rad`` (right-hand rule)."""
    return _rot(0, angle_rad)


def rot_y(angle_rad: np.ndarray | float) -> np.ndarray:
    """Rotation matrix (..., 3, 3) about y by ``angle_rad`` (right-hand rule)."""
    return _rot(1, angle_rad)


def rot_z(angle_rad: np.ndarray | float) -> np.ndarray:
    """Rotation matrix (..., 3, 3) about z by ``angle_rad`` (right-hand rule)."""
    return _rot(2, angle_rad)


def rpy_to_R(rpy_rad: np.ndarray) -> np.ndarray:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` for ``rpy_rad`` of shape (..., 3)."""
    rpy = np.asarray(rpy_rad, dtype=float)
    return rot_z(rpy[..., 2]) @ rot_y(rpy[..., 1]) @ rot_x(rpy[..., 0])


def R_to_rpy(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rpy_to_R` (..., 3) in radians; at pitch = +-90 deg roll is set to 0."""
    R = np.asarray(R, dtype=float)
    pitch = np.arctan2(-R[..., 2, 0], np.hypot(R[..., 0, 0], R[..., 1, 0]))
    gimbal = np.hypot(R[..., 0, 0], R[..., 1, 0]) < 1e-12
    roll = np.where(gimbal, 0.0, np.arctan2(R[..., 2, 1], R[..., 2, 2]))
    yaw = np.where(gimbal, np.arctan2(-R[..., 0, 1], R[..., 1, 1]), np.arctan2(R[..., 1, 0], R[..., 0, 0]))
    return np.stack([roll, pitch, yaw], axis=-1)


def make_T(R: ArrayLike, p: ArrayLike) -> np.ndarray:
    """Homogeneous transforms (..., 4, 4) from rotations (..., 3, 3) and translations (..., 3)."""
    R = np.asarray(R, dtype=float)
    p = np.asarray(p, dtype=float)
    shape = np.broadcast_shapes(R.shape[:-2], p.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = p
    T[..., 3, 3] = 1.0
    return T


def xyzrpy_to_T(xyz_mm: ArrayLike, rpy_deg: ArrayLike) -> np.ndarray:
    """Pose from a position in mm and URDF roll-pitch-yaw in degrees."""
    return make_T(rpy_to_R(np.radians(np.asarray(rpy_deg, dtype=float))), xyz_mm)


def T_to_xyzrpy(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(xyz_mm, rpy_deg)`` of a pose (inverse of :func:`xyzrpy_to_T`)."""
    T = np.asarray(T, dtype=float)
    return T[..., :3, 3].copy(), np.degrees(R_to_rpy(T[..., :3, :3]))


def inv_T(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (..., 4, 4) without a general matrix inverse."""
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_T(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def quat_sign(q_wxyz: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) with their sign chosen (``q`` and ``-q`` are one rotation): the first of ``w, x, y,
    z`` larger than :data:`QUAT_SIGN_TOL` in size is positive (a unit quaternion always has one of at least
    1/2). The same rule as ``w >= 0`` but where ``w`` is zero in exact arithmetic: there the sign of the
    rounding error, which differs between CPUs' kernels, would choose."""
    q = np.asarray(q_wxyz, dtype=float)
    if q.ndim == 2 and len(q) == 1:                    # one row (the twin's pose, read at every sample)
        row = q[0]
        lead = next((v for v in row.tolist() if abs(v) > QUAT_SIGN_TOL), 0.0)
        return -q if lead < 0.0 else q.copy()
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    lead = np.where(np.abs(w) > QUAT_SIGN_TOL, w,
                    np.where(np.abs(x) > QUAT_SIGN_TOL, x, np.where(np.abs(y) > QUAT_SIGN_TOL, y, z)))
    return np.where(lead[..., None] < 0.0, -q, q)


def quat_from_R(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) as ``(w, x, y, z)`` (sign: :func:`quat_sign`) from rotations (..., 3, 3).

    Shepperd's method: per row, divide by the largest of ``w, x, y, z`` so the
    result stays accurate for every rotation (each case computed on its rows only).
    """
    R = np.asarray(R, dtype=float)
    shape = R.shape[:-2]
    R = R.reshape(-1, 3, 3)
    m00, m11, m22 = R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]
    k = np.argmax(np.stack([m00 + m11 + m22, m00, m11, m22], axis=-1), axis=-1)
    q = np.empty((len(R), 4))
    for case in range(4):
        sel = np.flatnonzero(k == case)
        if not len(sel):
            continue
        M = R[sel] if len(sel) < len(R) else R
        a00, a11, a22 = M[:, 0, 0], M[:, 1, 1], M[:, 2, 2]
        d21, d02, d10 = M[:, 2, 1] - M[:, 1, 2], M[:, 0, 2] - M[:, 2, 0], M[:, 1, 0] - M[:, 0, 1]
        s01, s02, s12 = M[:, 0, 1] + M[:, 1, 0], M[:, 0, 2] + M[:, 2, 0], M[:, 1, 2] + M[:, 2, 1]
        if case == 0:
            t = np.sqrt(np.maximum(1.0 + a00 + a11 + a22, 1e-300)) * 2.0
            cols = (0.25 * t, d21 / t, d02 / t, d10 / t)
        elif case == 1:
            t = np.sqrt(np.maximum(1.0 + a00 - a11 - a22, 1e-300)) * 2.0
            cols = (d21 / t, 0.25 * t, s01 / t, s02 / t)
        elif case == 2:
            t = np.sqrt(np.maximum(1.0 - a00 + a11 - a22, 1e-300)) * 2.0
            cols = (d02 / t, s01 / t, 0.25 * t, s12 / t)
        else:
            t = np.sqrt(np.maximum(1.0 - a00 - a11 + a22, 1e-300)) * 2.0
            cols = (d10 / t, s02 / t, s12 / t, 0.25 * t)
        for j, col in enumerate(cols):
            q[sel, j] = col
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return quat_sign(q).reshape(shape + (4,))


def R_from_quat(q_wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) ``(w, x, y, z)`` (normalised first)."""
    q = np.asarray(q_wxyz, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def frame_from_z_axis(z_axis: np.ndarray, x_ref: np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) whose z column is ``z_axis`` and x column lies along ``x_ref``.

    ``x_ref`` (broadcast to (N, 3)) is projected onto the plane normal to z
    (Gram-Schmidt). Where it is (nearly) parallel to z, the base x axis (or,
    failing that, the base y axis) is used instead, so every row gets a frame.
    """
    z = np.atleast_2d(np.asarray(z_axis, dtype=float))
    if len(z) == 0:
        return np.empty((0, 3, 3))
    n = max(len(z), len(np.atleast_2d(x_ref)))
    z = np.broadcast_to(z, (n, 3))
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    xr = np.array(np.broadcast_to(np.asarray(x_ref, dtype=float), (n, 3)))
    bad = np.zeros(n, dtype=bool)
    for fallback in (None, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])):
        if fallback is not None:
            xr[bad] = fallback
        x = xr - np.einsum("ij,ij->i", xr, z)[:, None] * z
        nx = np.sqrt(np.einsum("ij,ij->i", x, x))
        bad = nx < 1e-6
        if not bad.any():
            break
    R = np.empty((n, 3, 3))
    R[:, :, 0] = x / nx[:, None]
    R[:, :, 2] = z
    R[:, :, 1] = np.cross(z, R[:, :, 0])
    return R


def rot_about_z(R: np.ndarray, angle_rad: np.ndarray | float) -> np.ndarray:
    """``R @ Rz(angle)``: rotate frames (..., 3, 3) about their own z axis (the nozzle axis)."""
    R = np.asarray(R, dtype=float)
    a = np.asarray(angle_rad, dtype=float)
    c, s = np.cos(a)[..., None], np.sin(a)[..., None]
    out = np.empty(np.broadcast_shapes(R.shape, a.shape + (3, 3)))
    x, y = R[..., :, 0], R[..., :, 1]
    out[..., :, 0] = c * x + s * y
    out[..., :, 1] = c * y - s * x
    out[..., :, 2] = R[..., :, 2]
    return out


def nlerp_quat(qa: np.ndarray, qb: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Normalised linear interpolation (N, 4) of quaternions ``(w, x, y, z)`` (N, 4) at fractions ``f`` (N,),
    the shorter way round, signed by :func:`quat_sign`: how the twin turns the tool between two rows."""
    sgn = np.where(np.sum(qa * qb, axis=-1) < 0, -1.0, 1.0)
    q = (1.0 - f)[:, None] * qa + (f * sgn)[:, None] * qb
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return quat_sign(q)
