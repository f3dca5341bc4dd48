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

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fabric.errors import ValidationError
from fabric.robot import frames
from fabric.robot.kinematics import IK_JUMP, IK_OK, pose_cols
from fabric.robot.model import RobotModel

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
    """Joints for TCP positions ``xyz_mm`` (N, 3) with nozzle axes ``z_axis`` ((3,) or (N, 3)), robot base frame.

    ``q_start`` seeds continuity (the approach ends there); ``x_ref`` ((3,) or
    (N, 3)) overrides the theta = 0 reference direction.
    """
    xyz = np.asarray(xyz_mm, dtype=float)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or not np.all(np.isfinite(xyz)):
        raise ValidationError("xyz_mm must be a finite (N, 3) array", field="xyz_mm")
    n = len(xyz)
    z0 = _unit_axes(z_axis, n)
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
    solver = _PathSolver(robot, p, _Frames(z0, xr), q_start, thetas, np.radians(jump_deg))
    return solver.solve()


def _unit_axes(z_axis: np.ndarray, n: int) -> np.ndarray:
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


class _Frames:
    """The nozzle frames ``R0_i`` (theta = 0) as columns ``x0, y0`` (3, N) and ``z0`` ((3, 1) or (3, N)).

    Built like :func:`fabric.robot.frames.frame_from_z_axis`: ``x_ref`` projected
    onto the plane normal to z (base x, then base y where it is parallel to z),
    ``y = z x x``. Columns keep every operation on contiguous rows of N numbers.
    """

    def __init__(self, z0: np.ndarray, xr: np.ndarray) -> None:
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
        self.x0, self.z0 = x, z0
        self.y0 = np.stack([z0[1] * x[2] - z0[2] * x[1], z0[2] * x[0] - z0[0] * x[2], z0[0] * x[1] - z0[1] * x[0]])
        self.const = z0.shape[1] == 1

    def cols(self, rows: slice | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``x0, y0, z0`` of some rows (z0 stays (3, 1) when constant)."""
        return self.x0[:, rows], self.y0[:, rows], self.z0 if self.const else self.z0[:, rows]

    def quats(self, theta_rad: np.ndarray) -> np.ndarray:
        """(N, 4) quaternions ``(w, x, y, z)``, w >= 0, of ``R0_i @ Rz(theta_i)``.

        With one nozzle axis every frame is ``B @ Rz(alpha_i)`` for a fixed ``B``
        (z column the axis), so the quaternion is ``q_B * (cos h, 0, 0, sin h)``
        with ``h = (alpha_i + theta_i) / 2``: no per-row matrix. Otherwise
        Shepperd's method on ``R0`` and the same product with ``h = theta_i / 2``.
        """
        if self.const:
            B = frames.frame_from_z_axis(self.z0[:, 0], np.array([1.0, 0.0, 0.0]))[0]
            qa = frames.quat_from_R(B)
            half = 0.5 * (np.arctan2(B[:, 1] @ self.x0, B[:, 0] @ self.x0) + theta_rad)
            w1, x1, y1, z1 = qa
        else:
            qa = frames.quat_from_R(np.stack([self.x0.T, self.y0.T, self.z0.T], axis=-1))
            half = 0.5 * np.broadcast_to(theta_rad, self.x0.shape[1:])
            w1, x1, y1, z1 = qa.T
        c, s = np.cos(half), np.sin(half)
        cols = (w1 * c - z1 * s, x1 * c + y1 * s, y1 * c - x1 * s, z1 * c + w1 * s)
        flip = cols[0] < 0.0
        zero = np.flatnonzero(cols[0] == 0.0)              # w = 0: largest component positive, as Shepperd's
        if len(zero):
            sub = [col if len(zero) == len(c) else col[zero] for col in cols[1:]]
            a = [np.abs(col) for col in sub]
            big = np.where((a[0] >= a[1]) & (a[0] >= a[2]), sub[0], np.where(a[1] >= a[2], sub[1], sub[2]))
            flip[zero] = big < 0.0
        q = np.stack(cols, axis=1)
        return np.negative(q, out=q, where=flip[:, None])


class _PathSolver:
    """The three steps of the module docstring over one path."""

    def __init__(self, robot: RobotModel, p: np.ndarray, fr: _Frames, q_start: np.ndarray,
                 thetas_deg: np.ndarray, jump_rad: float) -> None:
        self.robot, self.p, self.fr, self.q_start, self.cf = robot, p, fr, q_start, robot.closed_form
        self.thetas, self.jump_rad, self.n = thetas_deg, jump_rad, p.shape[1]

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
        x0, y0, z0 = self.fr.cols(rows)
        th = np.radians(theta_deg)
        c, s = np.cos(th), np.sin(th)
        ti = self.cf.tool_inv_T
        p = self.p[:, rows]
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

    def ik(self, rows: slice | np.ndarray, theta_deg: np.ndarray | float,
           seed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """IK of some rows at rotation(s) ``theta_deg``, continuous from ``seed``."""
        if self.cf is not None:
            return self.cf.ik_cols(self.flange_cols(rows, theta_deg), seed)
        return self.robot.ik(self.poses(rows, theta_deg), seed)

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
            th, q, status = found
            rot = np.full(self.n, th)
        quat = self.fr.quats(np.radians(rot))
        return PathIK(q, status, rot, quat, float(np.mean(status == IK_OK)), strategy)

    def _final(self, rot: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """IK of the whole path at rotation(s) ``rot`` (deg) with the jump test."""
        q, status = self.ik(slice(None), rot, self.q_start)
        jump = joint_jumps(self.robot, q, lambda r: self.poses(r, rot if np.ndim(rot) == 0 else rot[r]), self.jump_rad)
        status[jump & (status == IK_OK)] = IK_JUMP
        return q, status

    def _constant(self) -> tuple[float, np.ndarray, np.ndarray] | None:
        """Step 1: the best constant rotation verified on every row (theta, q, status), or None."""
        m = SAMPLE_ROWS if self.robot.closed_form is not None else SAMPLE_ROWS_NUMERIC
        rows = np.unique(np.linspace(0, self.n - 1, min(self.n, m)).round().astype(int))
        keys = []
        for k, th in enumerate(self.thetas):
            q, st = self.ik(rows, th, self.q_start)
            c = self.row_cost(q, st)
            if np.all(np.isfinite(c)):
                keys.append((float(c.max()), float(c.mean()), abs(float(th)), k))
        for _, _, _, k in sorted(keys)[:VERIFY_TOP]:
            q, status = self._final(float(self.thetas[k]))
            if np.all(status == IK_OK):
                return float(self.thetas[k]), q, status
        return None

    def _costs(self) -> np.ndarray:
        """Row costs (N, K) of every candidate (finite; infeasible = INFEASIBLE_COST)."""
        C = np.empty((self.n, len(self.thetas)), dtype=np.float32)
        for k, th in enumerate(self.thetas):
            q, st = self.ik(slice(None), th, self.q_start)
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
        q, status = self.ik(slice(None), rot, self.q_start)
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
                        if self.ik(np.array([i]), th, q[max(i - 1, 0)])[1][0] == IK_OK]
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
    qb, valid, _, _ = cf.branches_cols(pose_cols(T, cf.tool_inv_T))
    d = qb - q_prev[:, None, :]
    d -= 2.0 * np.pi * np.rint(d / (2.0 * np.pi))       # compare modulo 2*pi ...
    dist = np.where(valid, np.einsum("ijk,ijk->ij", d, d), np.inf)
    best = np.argmin(dist, axis=1)
    rows = np.arange(len(T))
    return q_prev + d[rows, best], valid[rows, best]     # ... and place next to q_prev


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
    q_mid, ok = _nearest_solution(robot, T_mid, q[rows - 1])
    dev = np.max(np.abs(q_mid - 0.5 * (q[rows - 1] + q[rows])), axis=1)
    jump[rows] = ~ok | (dev > JUMP_RATIO * step[rows - 1] + JUMP_SLACK_RAD)
    return jump
