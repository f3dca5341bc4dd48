"""The TCP's position alone for a serial chain of revolute joints, vectorised: no rotation matrices per row.

Forward kinematics of a whole pose multiplies a 3x3 rotation per joint and row.
The position of one point needs far less: walking back from the TCP, the point
in joint k's frame is turned about that joint's axis (a plane rotation for an
axis along x, y or z, either way: four products) and moved by the joint's fixed placement
in its parent (a rotation that is mostly zeros and ones in a URDF, so only its
other entries cost a product). The planner measures a million moves with it
(``fabric.planning.refine``) on the arms whose family has no point formula of
its own (UR, Panda).

:meth:`ChainPoint.of` answers None for a model it cannot walk (a joint that is
not revolute about one of its frame's axes, either way, a branch off the chain), and checks
itself against Pinocchio's forward kinematics before it is used.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pinocchio as pin

from fabric.robot import chain_native

__all__ = ["ChainPoint"]

_AXES = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2}
_CHECK_ROWS = 16
_CHECK_TOL_MM = 1e-7


class _Joint(NamedTuple):
    """One joint: its axis (0, 1, 2 for x, y, z of its frame), the axis's sign (+1, -1: a joint turning about
    -z turns about z by -q) and its placement in its parent (mm)."""

    axis: int
    sign: int
    R: np.ndarray
    t_mm: np.ndarray


def _axis(joint) -> tuple[int, int] | None:
    """The axis (0, 1, 2) and sign of a revolute joint about one of its frame's axes, else None."""
    name = joint.shortname()
    if name in _AXES:
        return _AXES[name], 1
    if name != "JointModelRevoluteUnaligned":
        return None
    u = np.asarray(joint.extract().axis, dtype=float)
    k = int(np.argmax(np.abs(u)))
    if abs(abs(u[k]) - 1.0) > 1e-12 or np.sum(np.abs(u)) - abs(u[k]) > 1e-12:
        return None
    return k, int(np.sign(u[k]))


class ChainPoint:
    """TCP positions (N, 3) mm in the model's root frame for joints (N, nq).

    The walk runs in C where the helper is built (``chain_native.py``, the same arithmetic: the same
    positions); ``use_native`` False keeps it in numpy (tests compare the two)."""

    use_native = True

    def __init__(self, joints: list[_Joint], tcp_mm: np.ndarray) -> None:
        self.joints = joints
        self.tcp_mm = np.asarray(tcp_mm, dtype=float)
        self._packed: chain_native.Packed | None = None

    def packed(self) -> chain_native.Packed:
        """The joints as the C helper reads them (made once)."""
        if self._packed is None:
            self._packed = chain_native.Packed(self.joints, self.tcp_mm)
        return self._packed

    @classmethod
    def of(cls, model: pin.Model, tcp_frame_id: int) -> ChainPoint | None:
        """The walk for ``model``'s TCP frame, or None where the model is not a chain of x/y/z revolute joints
        each the child of the one before (or where the walk does not reproduce Pinocchio's positions)."""
        joints: list[_Joint] = []
        for j in range(1, model.njoints):
            axis = _axis(model.joints[j])
            if axis is None or model.parents[j] != j - 1 or model.joints[j].idx_q != j - 1:
                return None
            M = model.jointPlacements[j]
            joints.append(_Joint(*axis, np.array(M.rotation), 1000.0 * np.array(M.translation)))
        frame = model.frames[tcp_frame_id]
        if frame.parentJoint != model.njoints - 1 or model.nq != len(joints):
            return None
        walk = cls(joints, 1000.0 * np.array(frame.placement.translation))
        return walk if walk._agrees(model, tcp_frame_id) else None

    def _agrees(self, model: pin.Model, tcp_frame_id: int) -> bool:
        rng = np.random.default_rng(0)
        lo = np.maximum(model.lowerPositionLimit, -np.pi)
        hi = np.minimum(model.upperPositionLimit, np.pi)
        q = rng.uniform(lo, hi, (_CHECK_ROWS, model.nq))
        data = model.createData()
        want = np.empty((_CHECK_ROWS, 3))
        for i, qi in enumerate(q):
            pin.framesForwardKinematics(model, data, qi)
            want[i] = 1000.0 * data.oMf[tcp_frame_id].translation
        return bool(np.max(np.abs(self(q) - want)) < _CHECK_TOL_MM)

    def __call__(self, q_rad: np.ndarray) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q_rad, dtype=float))
        if self.use_native:
            out = chain_native.points(self.packed(), q)
            if out is not None:
                return out
        n = len(q)
        v = [np.full(n, c) for c in self.tcp_mm]
        for k in range(len(self.joints) - 1, -1, -1):
            jt = self.joints[k]
            c, s = np.cos(q[:, k]), np.sin(q[:, k])
            if jt.sign < 0:
                s = -s
            a, b = (jt.axis + 1) % 3, (jt.axis + 2) % 3          # the plane the joint turns: (y, z), (z, x), (x, y)
            va, vb = v[a], v[b]
            v[a], v[b] = c * va - s * vb, s * va + c * vb
            v = _placed(jt.R, jt.t_mm, v)
        return np.stack(v, axis=1)


def _placed(R: np.ndarray, t: np.ndarray, v: list[np.ndarray]) -> list[np.ndarray]:
    """``R @ v + t`` for v given as three columns, the products by 0 and 1 skipped."""
    out = []
    for i in range(3):
        acc: np.ndarray | None = None
        for k in range(3):
            r = float(R[i, k])
            if abs(r) < 1e-15:
                continue
            term = v[k] if r == 1.0 else (-v[k] if r == -1.0 else r * v[k])
            acc = term if acc is None else acc + term
        acc = np.zeros_like(v[0]) if acc is None else acc
        out.append(acc + t[i] if t[i] != 0.0 else acc)
    return out
