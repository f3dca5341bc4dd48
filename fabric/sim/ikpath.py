"""Planning IK for printing: positions and nozzle axes in, joints out, using the free rotation about the nozzle.

Printing fixes only the nozzle axis (TCP +z); the rotation ``theta`` about it
is free (RoboDK searches +-180 deg in steps). The orientation of row i for a
candidate theta is ``R0_i @ Rz(theta)``, where ``R0_i`` has z along the nozzle
axis and x along ``x_ref`` (default: horizontal, pointing from the point back
towards the A1 axis, which for a vertical nozzle is the IRB 140's natural wrist
pose at theta = 0 and keeps A6 from winding as A1 turns).

How theta is chosen, cheapest first:

1. **Constant rotation.** Every candidate theta is solved on an evenly spaced
   subsample of the path (<= ``SAMPLE_ROWS`` rows, all candidates at once per
   IK call) and scored per row: infinite if the IK status is not OK, else a
   penalty for a joint within 15 % of its range from a limit and for
   ``|sin q5|`` under sin 15 deg (the wrist singularity; closed-form arms).
   Candidates feasible on the whole subsample are ranked by their worst row
   cost, then mean cost, then ``|theta|``; the best few are verified on every
   row (IK with continuity from ``q_start``, then a joint-jump test) and the
   first that passes everywhere is used: no wrist motion from the rotation.
2. **Piecewise rotation (Viterbi).** If no constant theta works, every
   candidate is solved on every row (closed-form arms; cost ``K`` full IK
   passes, costs kept as float32 (N, K)). Rows are grouped in blocks (at most
   ``MAX_BLOCKS``), a block's cost for a candidate is the sum of its row costs
   (infeasible rows cost ``INFEASIBLE_COST``), and a Viterbi pass over blocks
   picks the sequence minimising block costs plus ``ROT_CHANGE_COST`` per
   candidate step of rotation change between blocks, so theta changes rarely
   and slowly.
3. **Row repair.** A row still infeasible takes the feasible candidate nearest
   its block's theta, if any (numeric-IK arms skip step 2 and repair directly,
   at most ``REPAIR_MAX_ROWS`` rows: a path failing more widely is left marked).

Finally the chosen poses are solved once more over the whole path with joint
continuity and tested for joint jumps (:func:`joint_jumps`): a row is marked
``IK_JUMP`` when its move from the previous row is not a continuous motion of
one configuration (row 0 is reached by a joint move from ``q_start``, not tested).

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

from dataclasses import dataclass

import numpy as np

from fabric.errors import ValidationError
from fabric.sim import frames
from fabric.sim.kinematics import IK_JUMP, IK_OK
from fabric.sim.robot import RobotModel

__all__ = ["PathIK", "solve_path", "candidate_rotations_deg", "joint_jumps"]

SAMPLE_ROWS = 2048
SAMPLE_ROWS_NUMERIC = 64
REPAIR_MAX_ROWS = 2000
VERIFY_TOP = 3
MAX_BLOCKS = 2000
INFEASIBLE_COST = 1.0e3
ROT_CHANGE_COST = 1.0
LIMIT_MARGIN_R = 0.15
WRIST_SIN_SOFT = np.sin(np.radians(15.0))
JUMP_RATIO = 0.25
JUMP_SLACK_RAD = np.radians(1.0)


@dataclass
class PathIK:
    """Joint solution of a printing path (see module docstring)."""

    q_rad: np.ndarray          # (N, nq)
    status: np.ndarray         # (N,) uint8, IK_* codes (IK_JUMP for a joint jump)
    rot_deg: np.ndarray        # (N,) chosen rotation about the nozzle axis
    quat_wxyz: np.ndarray      # (N, 4) resulting TCP orientation, base frame
    feasible_r: float          # share of rows with status IK_OK
    strategy: str = "constant"  # "constant", "viterbi" or "repair"


def candidate_rotations_deg(rot_range_deg: tuple[float, float], rot_step_deg: float) -> np.ndarray:
    """Candidate rotations, ordered by |theta| (so ties prefer the smallest rotation)."""
    lo, hi = float(rot_range_deg[0]), float(rot_range_deg[1])
    if not (np.isfinite(lo) and np.isfinite(hi) and hi >= lo) or not rot_step_deg > 0:
        raise ValidationError("rot_range_deg must be (lo, hi) with hi >= lo and rot_step_deg > 0",
                              field="rot_range_deg", value=[lo, hi, rot_step_deg])
    th = np.arange(lo, hi + 1e-9, rot_step_deg)
    if hi - lo >= 360.0 - 1e-9:                      # full circle: -180 and +180 are the same
        th = th[th < lo + 360.0 - 1e-9]
    return th[np.argsort(np.abs(th), kind="stable")]


def solve_path(robot: RobotModel, xyz_mm: np.ndarray, z_axis: np.ndarray, q_start: np.ndarray,
               rot_range_deg: tuple[float, float] = (-180.0, 180.0), rot_step_deg: float = 15.0,
               x_ref: np.ndarray | None = None, jump_deg: float = 10.0) -> PathIK:
    """Joints for TCP positions ``xyz_mm`` (N, 3) with nozzle axes ``z_axis`` (N, 3), robot base frame.

    ``q_start`` seeds continuity (the approach ends there); ``x_ref`` ((3,) or
    (N, 3)) overrides the theta = 0 reference direction.
    """
    xyz = np.asarray(xyz_mm, dtype=float)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or not np.all(np.isfinite(xyz)):
        raise ValidationError("xyz_mm must be a finite (N, 3) array", field="xyz_mm")
    n = len(xyz)
    z = np.broadcast_to(np.asarray(z_axis, dtype=float), (n, 3))
    zn = np.linalg.norm(z, axis=1)
    if n and (not np.all(np.isfinite(zn)) or np.any(zn < 1e-9)):
        bad = int(np.argmax(~np.isfinite(zn) | (zn < 1e-9)))
        raise ValidationError(f"z_axis row {bad} is not a direction", field="z_axis", row=bad)
    q_start = np.asarray(q_start, dtype=float).reshape(-1)
    if q_start.shape != (robot.nq,):
        raise ValidationError(f"q_start needs {robot.nq} joints", field="q_start")
    thetas = candidate_rotations_deg(rot_range_deg, rot_step_deg)
    if n == 0:
        return PathIK(np.zeros((0, robot.nq)), np.zeros(0, np.uint8), np.zeros(0), np.zeros((0, 4)), 1.0)
    if x_ref is None:
        x_ref = np.column_stack([-xyz[:, 0], -xyz[:, 1], np.zeros(n)])   # towards the A1 axis
    R0 = frames.frame_from_z_axis(z / zn[:, None], x_ref)
    solver = _PathSolver(robot, xyz, R0, q_start, thetas, np.radians(jump_deg))
    return solver.solve()


class _PathSolver:
    """The three steps of the module docstring over one path."""

    def __init__(self, robot: RobotModel, xyz: np.ndarray, R0: np.ndarray, q_start: np.ndarray,
                 thetas_deg: np.ndarray, jump_rad: float) -> None:
        self.robot, self.xyz, self.R0, self.q_start = robot, xyz, R0, q_start
        self.thetas = thetas_deg
        self.jump_rad = jump_rad
        self.n = len(xyz)

    def poses(self, rows: np.ndarray | slice, theta_deg: np.ndarray | float) -> np.ndarray:
        R = frames.rot_about_z(self.R0[rows], np.radians(theta_deg))
        return frames.make_T(R, self.xyz[rows])

    def row_cost(self, q: np.ndarray, status: np.ndarray) -> np.ndarray:
        """Per-row cost of a joint solution (inf when infeasible)."""
        r = self.robot
        span = r.upper_rad - r.lower_rad
        margin = np.min(np.minimum(q - r.lower_rad, r.upper_rad - q) / span, axis=1)
        cost = np.maximum(0.0, LIMIT_MARGIN_R - margin) / LIMIT_MARGIN_R
        if r.closed_form is not None:
            cost += np.maximum(0.0, WRIST_SIN_SOFT - np.abs(np.sin(q[:, 4]))) / WRIST_SIN_SOFT
        return np.where(status == IK_OK, cost, np.inf)

    def solve(self) -> PathIK:
        found = self._constant()
        strategy = "constant"
        if found is None:
            strategy = "viterbi" if self.robot.closed_form is not None else "repair"
            rot = self._viterbi() if self.robot.closed_form is not None else np.zeros(self.n)
            rot = self._repair(rot)
            q, status = self._final(rot)
        else:
            rot, q, status = found
        R = frames.rot_about_z(self.R0, np.radians(rot))
        return PathIK(q, status, rot, frames.quat_from_R(R), float(np.mean(status == IK_OK)), strategy)

    def _final(self, rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        T = self.poses(slice(None), rot)
        q, status = self.robot.ik(T, self.q_start)
        jump = joint_jumps(self.robot, q, T, self.jump_rad)
        status = np.where(jump & (status == IK_OK), np.uint8(IK_JUMP), status).astype(np.uint8)
        return q, status

    def _constant(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Step 1: the best constant rotation verified on every row (rot, q, status), or None."""
        m = SAMPLE_ROWS if self.robot.closed_form is not None else SAMPLE_ROWS_NUMERIC
        rows = np.unique(np.linspace(0, self.n - 1, min(self.n, m)).round().astype(int))
        keys = []
        for k, th in enumerate(self.thetas):
            q, st = self.robot.ik(self.poses(rows, th), self.q_start)
            c = self.row_cost(q, st)
            if np.all(np.isfinite(c)):
                keys.append((float(c.max()), float(c.mean()), abs(float(th)), k))
        for _, _, _, k in sorted(keys)[:VERIFY_TOP]:
            rot = np.full(self.n, self.thetas[k])
            q, status = self._final(rot)
            if np.all(status == IK_OK):
                return rot, q, status
        return None

    def _costs(self) -> np.ndarray:
        """Row costs (N, K) of every candidate (finite; infeasible = INFEASIBLE_COST)."""
        C = np.empty((self.n, len(self.thetas)), dtype=np.float32)
        for k, th in enumerate(self.thetas):
            q, st = self.robot.ik(self.poses(slice(None), th), self.q_start)
            C[:, k] = np.minimum(self.row_cost(q, st), INFEASIBLE_COST)
        return C

    def _viterbi(self) -> np.ndarray:
        """Step 2: a slowly changing rotation per block of rows."""
        C = self._costs()
        self._C = C
        nb = min(self.n, MAX_BLOCKS)
        edges = np.linspace(0, self.n, nb + 1).round().astype(int)
        B = np.add.reduceat(C.astype(np.float64), edges[:-1], axis=0)       # (nb, K)
        th = self.thetas
        d = np.abs(th[:, None] - th[None, :])
        if th.max() - th.min() + (th[1] - th[0] if len(th) > 1 else 0) >= 360.0 - 1e-9:
            d = np.minimum(d, 360.0 - d)                                    # rotations wrap
        step = np.min(np.diff(np.sort(th))) if len(th) > 1 else 1.0
        trans = ROT_CHANGE_COST * d / step                                  # (K_prev, K_next)
        acc = B[0].copy()
        back = np.empty((nb, len(th)), dtype=np.intp)
        for b in range(1, nb):
            tot = acc[:, None] + trans
            back[b] = np.argmin(tot, axis=0)
            acc = tot[back[b], np.arange(len(th))] + B[b]
        path = np.empty(nb, dtype=np.intp)
        path[-1] = int(np.argmin(acc))
        for b in range(nb - 1, 0, -1):
            path[b - 1] = back[b, path[b]]
        return np.repeat(th[path], np.diff(edges))

    def _repair(self, rot: np.ndarray) -> np.ndarray:
        """Step 3: infeasible rows take the nearest feasible candidate rotation."""
        q, status = self.robot.ik(self.poses(slice(None), rot), self.q_start)
        bad = np.flatnonzero(status != IK_OK)
        if not len(bad):
            return rot
        C = getattr(self, "_C", None)
        rot = rot.copy()
        for i in bad[:REPAIR_MAX_ROWS]:
            if C is not None:
                feas = np.flatnonzero(C[i] < INFEASIBLE_COST)
            else:
                feas = [k for k, th in enumerate(self.thetas)
                        if self.robot.ik(self.poses([i], th), q[max(i - 1, 0)])[1][0] == IK_OK]
                feas = np.asarray(feas, dtype=int)
            if len(feas):
                rot[i] = self.thetas[feas[np.argmin(np.abs(self.thetas[feas] - rot[i]))]]
        return rot


def _nearest_solution(robot: RobotModel, T: np.ndarray, q_prev: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the IK solution of T (M, 4, 4) nearest ``q_prev`` (M, nq), and whether it is valid."""
    cf = robot.closed_form
    if cf is None:
        out = np.empty_like(q_prev)
        ok = np.empty(len(T), dtype=bool)
        for i in range(len(T)):
            qi, st = robot.ik(T[i], q_prev[i])
            out[i], ok[i] = qi[0], st[0] == IK_OK
        return out, ok
    qb, valid, _, _ = cf.branches(T @ frames.inv_T(robot.tool_T))
    d = qb - q_prev[:, None, :]
    d -= 2.0 * np.pi * np.rint(d / (2.0 * np.pi))       # compare modulo 2*pi ...
    dist = np.where(valid, np.einsum("ijk,ijk->ij", d, d), np.inf)
    best = np.argmin(dist, axis=1)
    rows = np.arange(len(T))
    return q_prev + d[rows, best], valid[rows, best]     # ... and place next to q_prev


def joint_jumps(robot: RobotModel, q: np.ndarray, T: np.ndarray, check_rad: float = np.radians(10.0)) -> np.ndarray:
    """Rows (N,) whose move from the previous row is not continuous (module docstring: jump test).

    ``q`` (N, nq) joints and ``T`` (N, 4, 4) the TCP poses they reach (mm).
    """
    n = len(q)
    jump = np.zeros(n, dtype=bool)
    if n < 2:
        return jump
    dq = np.diff(q, axis=0)
    step = np.max(np.abs(dq), axis=1)
    rows = np.flatnonzero(step > check_rad) + 1
    if not len(rows):
        return jump
    qa = frames.quat_from_R(T[rows - 1, :3, :3])
    qb = frames.quat_from_R(T[rows, :3, :3])
    qb *= np.where(np.sum(qa * qb, axis=1) < 0.0, -1.0, 1.0)[:, None]
    T_mid = frames.make_T(frames.R_from_quat(qa + qb), 0.5 * (T[rows - 1, :3, 3] + T[rows, :3, 3]))
    q_mid, ok = _nearest_solution(robot, T_mid, q[rows - 1])
    dev = np.max(np.abs(q_mid - 0.5 * (q[rows - 1] + q[rows])), axis=1)
    jump[rows] = ~ok | (dev > JUMP_RATIO * step[rows - 1] + JUMP_SLACK_RAD)
    return jump
