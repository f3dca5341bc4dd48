"""Joint-jump test of a joint path: is each row's move a continuous motion of one configuration?

Jump test. A fixed joint-step threshold cannot tell a long travel move (250 mm
across the plate legitimately turns A2/A3 by tens of degrees) from a
configuration change. So rows whose largest joint step exceeds ``jump_deg``
(default 10 deg) get a midpoint test: the pose halfway along the linear move
(position midpoint, orientation slerp midpoint) is solved from the previous
row's joints, and the move is continuous only if that solution lies near the
joint-space midpoint, within ``JUMP_RATIO`` (25 %) of the step plus 1 deg. A
branch change (wrist flip, elbow or shoulder change) or a 2*pi relocation of a
multi-turn joint puts the continuous midpoint solution next to the start, half
a step (50 %) away from the joint midpoint, and is caught; the curvature of a
smooth move between two points of one configuration stays well under 25 %.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from fabric.robot import frames
from fabric.robot.kinematics import IK_OK, pose_cols
from fabric.robot.model import RobotModel

__all__ = ["joint_jumps", "JUMP_RATIO", "JUMP_SLACK_RAD"]

JUMP_RATIO = 0.25                       # midpoint deviation allowed, as a share of the joint step
JUMP_SLACK_RAD = np.radians(1.0)        # ... plus this


class _Nearest(NamedTuple):
    """Per row, the IK solution nearest the previous joints, and whether it is a valid one."""

    q_rad: np.ndarray          # (M, nq)
    valid: np.ndarray          # (M,) bool


def _nearest_solution(robot: RobotModel, T: np.ndarray, q_prev: np.ndarray,
                      q_free: np.ndarray | None = None) -> _Nearest:
    """Per row, the IK solution of T (M, 4, 4) nearest ``q_prev`` (M, nq), and whether it is valid.

    ``q_free``: a redundant closed form's parameter joint per row (default: the solver's held value)."""
    cf = robot.closed_form
    rows_solver = getattr(robot.solver, "solve_rows", None)
    if cf is None and rows_solver is not None:          # batched DLS: every row from its own previous joints
        q, status = rows_solver(T, q_prev)
        return _Nearest(q, status == IK_OK)
    if cf is None:
        out = np.empty_like(q_prev)
        ok = np.empty(len(T), dtype=bool)
        for i in range(len(T)):
            qi, st = robot.ik(T[i], q_prev[i])
            out[i] = qi[0]
            ok[i] = st[0] == IK_OK
        return _Nearest(out, ok)
    qb, valid, _, _ = cf.branches_cols(pose_cols(T, cf.tool_inv_T), q_free=q_free)
    d = qb - q_prev[:, None, :]
    d -= 2.0 * np.pi * np.rint(d / (2.0 * np.pi))       # compare modulo 2*pi ...
    dist = np.where(valid, np.einsum("ijk,ijk->ij", d, d), np.inf)
    best = np.argmin(dist, axis=1)
    rows = np.arange(len(T))
    return _Nearest(q_prev + d[rows, best], valid[rows, best])      # ... and place next to q_prev


def joint_jumps(robot: RobotModel, q: np.ndarray, T: np.ndarray | Callable[[np.ndarray], np.ndarray],
                check_rad: float = np.radians(10.0)) -> np.ndarray:
    """Rows (N,) whose move from the previous row is not continuous (module docstring: jump test).

    ``q`` (N, nq) joints and ``T`` (N, 4, 4) the TCP poses they reach (mm), or
    a function giving the poses of some rows (only the rows tested are built).
    """
    poses = T if callable(T) else (lambda rows: T[rows])
    n = len(q)
    jump = np.zeros(n, dtype=bool)
    if n < 2:
        return jump
    dq = np.abs(q[1:] - q[:-1])
    step = dq[:, 0].copy()
    for j in range(1, dq.shape[1]):                      # column by column: a row max over 6 is slow
        np.maximum(step, dq[:, j], out=step)
    rows = np.flatnonzero(step > check_rad) + 1
    if not len(rows):
        return jump
    Ta, Tb = poses(rows - 1), poses(rows)
    qa = frames.quat_from_R(Ta[:, :3, :3])
    qb = frames.quat_from_R(Tb[:, :3, :3])
    qb *= np.where(np.sum(qa * qb, axis=1) < 0.0, -1.0, 1.0)[:, None]
    T_mid = frames.make_T(frames.R_from_quat(qa + qb), 0.5 * (Ta[:, :3, 3] + Tb[:, :3, 3]))
    cf = robot.closed_form
    free = None if cf is None or cf.free_joint is None else 0.5 * (q[rows - 1, cf.free_joint] + q[rows, cf.free_joint])
    mid = _nearest_solution(robot, T_mid, q[rows - 1], free)       # a redundant arm's parameter: halfway too
    dev = np.max(np.abs(mid.q_rad - 0.5 * (q[rows - 1] + q[rows])), axis=1)
    jump[rows] = ~mid.valid | (dev > JUMP_RATIO * step[rows - 1] + JUMP_SLACK_RAD)
    return jump
