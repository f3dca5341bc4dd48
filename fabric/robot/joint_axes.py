"""The joint axes of a serial arm at its zero configuration, read from Pinocchio, and the line geometry on them.

Every revolute chain is fully described by its axes at ``q = 0`` (the
product-of-exponentials form): joint i turns about the line through
``points_mm[i]`` along ``directions[i]`` (base frame), and the flange sits at
``flange_T`` when all joints are zero. The closed-form families
(``opw_derive.py``, ``ur_derive.py``) read their parameters from these lines,
so a URDF's own link frames, rpy conventions and zero positions do not matter.

Pinocchio gives each axis as a column of the world-frame Jacobian at ``q = 0``:
the spatial velocity ``(v, w)`` of a unit rate about the axis, with
``v = -w x p`` for any point p on it, so ``p = w x v`` is the axis point
nearest the base origin.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

__all__ = ["JointAxes", "joint_axes", "line_distance_mm", "line_closest_points", "fk_mismatch"]


@dataclass(frozen=True)
class JointAxes:
    """Axes of the actuated joints at ``q = 0`` (base frame, mm) and the flange pose there."""

    directions: np.ndarray     # (nq, 3) unit vectors; zero rows for joints that are not revolute
    points_mm: np.ndarray      # (nq, 3) the axis point nearest the base origin
    flange_T: np.ndarray       # (4, 4) mm
    kinds: tuple[str, ...]     # Pinocchio joint short names ("JointModelRZ", ...)

    @property
    def revolute(self) -> np.ndarray:
        """(nq,) bool: joints that turn about a fixed axis with one coordinate."""
        return np.array([k.startswith("JointModelR") and "UB" not in k for k in self.kinds])


def joint_axes(model: pin.Model, flange_frame_id: int) -> JointAxes:
    """The :class:`JointAxes` of ``model`` with the flange frame ``flange_frame_id``."""
    data = model.createData()
    q0 = pin.neutral(model)
    pin.computeJointJacobians(model, data, q0)
    pin.updateFramePlacements(model, data)
    dirs, pts, kinds = [], [], []
    for j in range(1, model.njoints):
        kinds.append(str(model.joints[j].shortname()))
        col = pin.getJointJacobian(model, data, j, pin.ReferenceFrame.WORLD)[:, model.joints[j].idx_v]
        v, w = col[:3], col[3:]
        norm = float(np.linalg.norm(w))
        if norm < 1e-9:                                 # prismatic or fixed: no axis to turn about
            dirs.append(np.zeros(3))
            pts.append(np.zeros(3))
            continue
        w = w / norm
        dirs.append(w)
        pts.append(np.cross(w, v / norm) * 1000.0)
    T = data.oMf[flange_frame_id].homogeneous.copy()
    T[:3, 3] *= 1000.0
    return JointAxes(np.array(dirs).reshape(-1, 3), np.array(pts).reshape(-1, 3), T, tuple(kinds))


def line_closest_points(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """The closest points of two lines ``p + t d`` (unit d); for parallel lines, p1 and its foot on line 2."""
    w = p1 - p2
    b = float(d1 @ d2)
    den = 1.0 - b * b
    if den < 1e-12:
        return p1, p2 + float(w @ d2) * d2
    t1 = (b * float(w @ d2) - float(w @ d1)) / den
    t2 = (float(w @ d2) - b * float(w @ d1)) / den
    return p1 + t1 * d1, p2 + t2 * d2


def line_distance_mm(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray) -> float:
    """Shortest distance between two lines (mm)."""
    a, b = line_closest_points(p1, d1, p2, d2)
    return float(np.linalg.norm(a - b))


def fk_mismatch(model: pin.Model, flange_frame_id: int, fk_flange: Callable[[np.ndarray], np.ndarray],
                lower_rad: np.ndarray, upper_rad: np.ndarray, n: int = 32) -> tuple[float, float]:
    """Largest position (mm) and rotation (rad) difference between ``fk_flange(q)`` and Pinocchio.

    Over ``n`` random joint vectors within the limits (clipped to one turn each
    way), seeded so the check is repeatable.
    """
    rng = np.random.default_rng(20)
    q = rng.uniform(np.maximum(lower_rad, -np.pi), np.minimum(upper_rad, np.pi), (n, model.nq))
    data = model.createData()
    ref = np.empty((n, 4, 4))
    for i in range(n):
        pin.framesForwardKinematics(model, data, q[i])
        ref[i] = data.oMf[flange_frame_id].homogeneous
    ref[:, :3, 3] *= 1000.0
    ours = np.asarray(fk_flange(q))
    pos = float(np.abs(ours[:, :3, 3] - ref[:, :3, 3]).max())
    rot = float(np.abs(ours[:, :3, :3] - ref[:, :3, :3]).max())
    return pos, rot
