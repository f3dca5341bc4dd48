"""Planning IK for printing: positions and nozzle axes in, joints out, using the free rotation about the nozzle.

Printing fixes only the nozzle axis (TCP +z); the rotation ``theta`` about it
is free (RoboDK searches +-180 deg in steps). The orientation of row i for a
candidate theta is ``R0_i @ Rz(theta)``, where ``R0_i`` has z along the nozzle
axis and x along ``x_ref`` (default: horizontal, pointing from the point back
towards the A1 axis, which for a vertical nozzle is the IRB 140's natural wrist
pose at theta = 0 and keeps A6 from winding as A1 turns). On a 7-axis arm of
the Panda type the closed form holds A7 (its redundancy parameter) and theta
is what moves the elbow's swivel: with the nozzle along A7 that covers every
solution (``panda.py``).

How theta is chosen, cheapest first:

1. **Constant rotation.** Every candidate theta is solved on an evenly spaced
   subsample of the path (<= ``SAMPLE_ROWS`` rows, all candidates at once per
   IK call) and scored per row: infinite if the IK status is not OK, else a
   penalty for a joint within 15 % of its range from a limit and for
   the wrist bend's ``|sin|`` under sin 15 deg (the family's wrist singularity;
   closed-form arms; a redundant arm's batched IK keeps away from limits itself).
   Candidates feasible on the whole subsample are ranked first by whether
   their first row continues from ``q_start`` (no joint further than the jump
   threshold: a planner solving a long path block by block keeps the previous
   block's configuration instead of jumping at the boundary; on a 7-axis arm
   the rotation moves the whole arm, not the wrist alone), then by their worst
   row cost, mean cost and ``|theta|``; the best few are verified on every
   row (IK with continuity from ``q_start``, then a joint-jump test) and the
   first that passes everywhere is used: no wrist motion from the rotation.
2. **Piecewise rotation (Viterbi).** If no constant theta works, every
   candidate is solved on every row (closed-form arms; cost ``K`` full IK
   passes, costs kept as float32 (N, K); also the batched DLS IK of redundant arms). Rows are grouped in blocks (at most
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

The joint-jump test is :func:`fabric.robot.joint_jumps.joint_jumps`; the nozzle frames
and their quaternions are :class:`fabric.robot.nozzle_frames.NozzleFrames`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from fabric.robot import nozzle_native
from fabric.robot.batch_dls import BatchDLSIK
from fabric.robot.joint_jumps import joint_jumps
from fabric.robot.kinematics import IK_JUMP, IK_OK
from fabric.robot.model import RobotModel
from fabric.robot.nozzle_frames import NozzleFrames, unit_axes
from fabric.wire.errors import ValidationError

__all__ = ["PathIK", "solve_path", "candidate_rotations_deg", "joint_jumps"]

SAMPLE_ROWS = 2048              # subsample of step 1 (closed-form arms)
SAMPLE_ROWS_NUMERIC = 64        # ... numeric-IK arms
PRECHECK_EVERY = 8              # step 1 on a redundant closed form: sample rows of the all-branch pre-test
REPAIR_MAX_ROWS = 2000          # rows step 3 repairs at most
VERIFY_TOP = 3                  # best constant rotations verified on every row
MAX_BLOCKS = 2000               # blocks of the Viterbi pass
INFEASIBLE_COST = 1.0e3         # row cost of an infeasible candidate in step 2
ROT_CHANGE_COST = 1.0           # per candidate step of rotation change between blocks
LIMIT_MARGIN_R = 0.15           # joints nearer a limit than this share of their range are penalised
WRIST_SIN_SOFT = np.sin(np.radians(15.0))


@dataclass
class PathIK:
    """Joint solution of a printing path (see module docstring)."""

    q_rad: np.ndarray          # (N, nq)
    status: np.ndarray         # (N,) uint8, IK_* codes (IK_JUMP for a joint jump)
    rot_deg: np.ndarray        # (N,) chosen rotation about the nozzle axis
    quat_wxyz: np.ndarray      # (N, 4) resulting TCP orientation, base frame
    feasible_r: float          # share of rows with status IK_OK
    strategy: str = "constant"  # "constant", "viterbi" or "repair"


class JointSolution(NamedTuple):
    """Joints of some rows and their IK status codes."""

    q_rad: np.ndarray          # (M, nq)
    status: np.ndarray         # (M,) uint8


class ConstantRotation(NamedTuple):
    """Step 1's result: one rotation for the whole path and its verified solution."""

    theta_deg: float
    solution: JointSolution


class _Rank(NamedTuple):
    """How step 1 ranks a feasible candidate (sorted ascending): a start without a jump, then worst row cost."""

    jumps_from_start: bool
    worst_cost: float
    mean_cost: float
    abs_theta_deg: float
    candidate: int


def candidate_rotations_deg(rot_range_deg: tuple[float, ...], rot_step_deg: float) -> np.ndarray:
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
               rot_range_deg: tuple[float, ...] = (-180.0, 180.0), rot_step_deg: float = 15.0,
               x_ref: np.ndarray | None = None, jump_deg: float = 10.0) -> PathIK:
    """Joints for TCP positions ``xyz_mm`` (N, 3) with nozzle axes ``z_axis`` ((3,) or (N, 3)), robot base frame.

    ``q_start`` seeds continuity (the approach ends there); ``x_ref`` ((3,) or
    (N, 3)) overrides the theta = 0 reference direction.
    """
    xyz = np.asarray(xyz_mm, dtype=float)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or not np.all(np.isfinite(xyz)):
        raise ValidationError("xyz_mm must be a finite (N, 3) array", field="xyz_mm")
    n = len(xyz)
    z0 = unit_axes(z_axis, n)
    q_start = np.asarray(q_start, dtype=float).reshape(-1)
    if q_start.shape != (robot.nq,):
        raise ValidationError(f"q_start needs {robot.nq} joints", field="q_start")
    thetas = candidate_rotations_deg(rot_range_deg, rot_step_deg)
    if n == 0:
        return PathIK(np.zeros((0, robot.nq)), np.zeros(0, np.uint8), np.zeros(0), np.zeros((0, 4)), 1.0)
    p = np.ascontiguousarray(xyz.T)
    if x_ref is None:                                   # towards the A1 axis
        xr = np.stack([-p[0], -p[1], np.zeros(n)])
    else:
        xr = np.array(np.broadcast_to(np.asarray(x_ref, dtype=float), (n, 3)).T)
    solver = _PathSolver(robot, p, NozzleFrames(z0, xr), q_start, thetas, np.radians(jump_deg))
    return solver.solve()


class _PathSolver:
    """The three steps of the module docstring over one path."""

    def __init__(self, robot: RobotModel, p: np.ndarray, fr: NozzleFrames, q_start: np.ndarray,
                 thetas_deg: np.ndarray, jump_rad: float) -> None:
        self.robot = robot
        self.cf = robot.closed_form             # None for numeric-IK arms
        # solvers that take every row at once (closed form, batched DLS) get the whole-path steps
        self.batched = self.cf is not None or bool(getattr(robot.solver, "batched", False))
        self.p = p                              # (3, N) TCP positions
        self.fr = fr
        self.q_start = q_start
        self.thetas = thetas_deg
        self.jump_rad = jump_rad
        self.n = p.shape[1]
        self._costs_nk: np.ndarray | None = None    # step 2's row costs, reused by step 3
        self._gather_rows: slice | np.ndarray | None = None      # the rows _gathered last, and what it gathered
        self._gather: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None

    def poses(self, rows: slice | np.ndarray, theta_deg: np.ndarray | float) -> np.ndarray:
        """TCP poses (M, 4, 4) of some rows at rotation(s) ``theta_deg``."""
        x0, y0, z0 = self.fr.cols(rows)
        th = np.radians(theta_deg)
        c, s = np.cos(th), np.sin(th)
        p = self.p[:, rows]
        T = np.zeros((p.shape[1], 4, 4))
        T[:, :3, 0] = (c * x0 + s * y0).T
        T[:, :3, 1] = (c * y0 - s * x0).T
        T[:, :3, 2] = np.broadcast_to(z0, p.shape).T
        T[:, :3, 3] = p.T
        T[:, 3, 3] = 1.0
        return T

    def flange_cols(self, rows: slice | np.ndarray, theta_deg: np.ndarray | float) -> np.ndarray:
        """Flange poses of some rows as IK columns (9, M): ``R0 Rz(theta) tool_inv``, no 4x4 per row.

        Each flange column is ``R0 @ (Rz(theta) @ m)`` for a column ``m`` of the
        TCP -> flange transform: ``x0 * a + y0 * b + z0 * m_z`` with
        ``a, b = Rz(theta) (m_x, m_y)``, zero terms skipped.
        """
        x0, y0, z0, p = self._gathered(rows)
        th = np.radians(theta_deg)
        c, s = np.cos(th), np.sin(th)
        assert self.cf is not None, "flange columns feed the closed-form IK only"
        ti = self.cf.tool_inv_T
        if isinstance(rows, slice) and rows == slice(None) and self.fr.use_native:      # every row: in C
            done = nozzle_native.flange_cols(p, x0, y0, z0, c, s, ti)
            if done is not None:
                return done
        out = np.empty((9, p.shape[1]))
        for k, m in enumerate((ti[:3, 3], ti[:3, 2], ti[:3, 1])):
            o = out[3 * k:3 * k + 3]
            o[...] = p if k == 0 else 0.0
            if m[0] != 0.0 or m[1] != 0.0:
                o += x0 * (c * m[0] - s * m[1])
                o += y0 * (s * m[0] + c * m[1])
            if m[2] != 0.0:
                o += z0 * m[2]
        return out

    def _gathered(self, rows: slice | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``x0, y0, z0`` and the positions of some rows, gathered once for the same ``rows`` asked again (step 1
        asks its sample rows at every candidate rotation)."""
        if self._gather is None or self._gather_rows is not rows:
            self._gather = (*self.fr.cols(rows), self.p[:, rows])
            self._gather_rows = rows
        return self._gather

    def ik(self, rows: slice | np.ndarray, theta_deg: np.ndarray | float, seed: np.ndarray) -> JointSolution:
        """IK of some rows at rotation(s) ``theta_deg``, continuous from ``seed``."""
        if self.cf is not None:
            q, status = self.cf.ik_cols(self.flange_cols(rows, theta_deg), seed)
        else:
            q, status = self.robot.ik(self.poses(rows, theta_deg), seed)
        return JointSolution(q, status)

    def ik_candidates(self, rows: slice | np.ndarray) -> list[JointSolution]:
        """IK of some rows at every candidate rotation, each continuous from ``q_start``.

        The batched DLS solver gets all candidates in one call (its rows seed each other only
        within a candidate's run of rows), without retrying failed rows (a candidate failing on the
        sample is dropped anyway); the closed form takes them one by one (each call is fast).
        """
        solver = self.robot.solver
        if not isinstance(solver, BatchDLSIK):
            return [self.ik(rows, th, self.q_start) for th in self.thetas]
        T = np.concatenate([self.poses(rows, th) for th in self.thetas])
        q, status = solver.solve(T, self.q_start, retry=False)      # feasibility: no retries of failed rows
        m = len(T) // len(self.thetas)
        return [JointSolution(q[k * m:(k + 1) * m], status[k * m:(k + 1) * m]) for k in range(len(self.thetas))]

    def row_cost(self, q: np.ndarray, status: np.ndarray) -> np.ndarray:
        """Per-row cost of a joint solution (inf when infeasible)."""
        r = self.robot
        span = r.upper_rad - r.lower_rad
        margin = np.min(np.minimum(q - r.lower_rad, r.upper_rad - q) / span, axis=1)
        cost = np.maximum(0.0, LIMIT_MARGIN_R - margin) / LIMIT_MARGIN_R
        if r.closed_form is not None:
            # the family's wrist singularity (theta5 = 0 for OPW and UR arms; for the Panda type the shoulder's
            # gimbal lock or the two wrist solutions meeting, ``panda.py``)
            cost += np.maximum(0.0, WRIST_SIN_SOFT - r.closed_form.wrist_sin(q)) / WRIST_SIN_SOFT
        return np.where(status == IK_OK, cost, np.inf)

    def solve(self) -> PathIK:
        found = self._constant()
        if found is not None:
            rot = np.full(self.n, found.theta_deg)
            sol = found.solution
            strategy = "constant"
        else:
            if self.batched:
                strategy = "viterbi"
                rot = self._viterbi()
            else:
                strategy = "repair"
                rot = np.zeros(self.n)
            rot = self._repair(rot)
            sol = self._final(rot)
        quat = self.fr.quats(np.radians(rot))
        return PathIK(sol.q_rad, sol.status, rot, quat, float(np.mean(sol.status == IK_OK)), strategy)

    def _final(self, rot: np.ndarray | float) -> JointSolution:
        """IK of the whole path at rotation(s) ``rot`` (deg) with the jump test."""
        q, status = self.ik(slice(None), rot, self.q_start)

        def poses(rows: np.ndarray) -> np.ndarray:
            return self.poses(rows, rot[rows] if isinstance(rot, np.ndarray) and rot.ndim else rot)

        jump = joint_jumps(self.robot, q, poses, self.jump_rad)
        status[jump & (status == IK_OK)] = IK_JUMP
        return JointSolution(q, status)

    def _constant(self) -> ConstantRotation | None:
        """Step 1: the best constant rotation verified on every row, or None."""
        m = SAMPLE_ROWS if self.batched else SAMPLE_ROWS_NUMERIC
        rows = np.unique(np.linspace(0, self.n - 1, min(self.n, m)).round().astype(int))
        ranked: list[_Rank] = []
        for k, (th, sol) in enumerate(zip(self.thetas, self._sample_candidates(rows), strict=True)):
            if sol is None:
                continue
            c = self.row_cost(*sol)
            if np.all(np.isfinite(c)):
                # costs equal but for rounding are a tie (the smallest rotation wins): a rotation about the
                # nozzle changes only A6 on a vertical nozzle, and the same path cut into blocks must rank alike
                jumps = bool(np.max(np.abs(sol.q_rad[0] - self.q_start)) > self.jump_rad)
                ranked.append(_Rank(jumps, round(float(c.max()), 9), round(float(c.mean()), 9), abs(float(th)), k))
        for rank in sorted(ranked)[:VERIFY_TOP]:
            theta = float(self.thetas[rank.candidate])
            sol = self._final(theta)
            if np.all(sol.status == IK_OK):
                return ConstantRotation(theta, sol)
        return None

    def _sample_candidates(self, rows: np.ndarray) -> list[JointSolution | None]:
        """Step 1's IK of the sample rows for every candidate; None for a candidate some row cannot take at all.

        On a redundant closed form (the Panda type) the rotation moves the whole arm and most candidates leave
        the joint limits on many rows: an all-branch test without continuity on every ``PRECHECK_EVERY``-th
        sample row (a row with no branch within limits and clear of singularities can have no OK status)
        drops those, every candidate in one call, before the continuity solve, whose windows of all branches
        cost several times more on sparse sample rows. It only saves work: a candidate it keeps is solved and
        ranked as before.
        """
        cf = self.cf
        if cf is None or cf.free_joint is None:
            return list(self.ik_candidates(rows))
        few = rows[::PRECHECK_EVERY]
        _, ok, _, sing = cf.branches_cols(np.concatenate([self.flange_cols(few, th) for th in self.thetas], axis=1))
        takes = np.all(np.any(ok & ~sing, axis=1).reshape(len(self.thetas), -1), axis=1)
        return [self.ik(rows, th, self.q_start) if t else None for th, t in zip(self.thetas, takes, strict=True)]

    def _costs(self) -> np.ndarray:
        """Row costs (N, K) of every candidate (finite; infeasible = INFEASIBLE_COST)."""
        C = np.empty((self.n, len(self.thetas)), dtype=np.float32)
        for k, sol in enumerate(self.ik_candidates(slice(None))):
            C[:, k] = np.minimum(self.row_cost(*sol), INFEASIBLE_COST)
        return C

    def _viterbi(self) -> np.ndarray:
        """Step 2: a slowly changing rotation per block of rows."""
        C = self._costs()
        self._costs_nk = C
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
        q, status = self.ik(slice(None), rot, self.q_start)
        bad = np.flatnonzero(status != IK_OK)
        if not len(bad):
            return rot
        C = self._costs_nk
        rot = rot.copy()
        for i in bad[:REPAIR_MAX_ROWS]:
            if C is not None:
                feas = np.flatnonzero(C[i] < INFEASIBLE_COST)
            else:
                seed = q[max(i - 1, 0)]
                feas = np.asarray([k for k, th in enumerate(self.thetas)
                                   if self.ik(np.array([i]), th, seed).status[0] == IK_OK], dtype=int)
            if len(feas):
                rot[i] = self.thetas[feas[np.argmin(np.abs(self.thetas[feas] - rot[i]))]]
        return rot
