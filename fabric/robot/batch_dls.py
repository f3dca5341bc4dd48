"""Batched numeric IK for redundant arms of no closed-form family: damped least squares on every target at once.

The fallback for any revolute arm that fits no family (``ik_family.py``), such as a 7-axis arm not of the Panda
type (``panda.py``); numpy throughout.

The arm is its product-of-exponentials form read from the URDF
(:class:`~fabric.robot.joint_axes.JointAxes`: each joint's axis line at
``q = 0`` and the flange pose there), so forward kinematics, the Jacobian and
the update are array operations over all N targets at once; no Pinocchio call
per row. Lengths are metres inside the iteration so that a millimetre and a
milliradian weigh about the same.

One iteration, for every row still moving:

* FK: ``T = exp(xi_1 q_1) ... exp(xi_n q_n) M`` (Rodrigues per joint), with the
  current axis lines ``w_i``, ``p_i`` gathered on the way;
* error ``e = (p_target - p, 1/2 sum_k x_k x x_k*)`` (position; the rotation
  vector ``sin(angle) * axis`` of ``R* R^T``, exact to first order);
* geometric Jacobian at the TCP, ``J_i = (w_i x (p - p_i), w_i)``;
* step ``dq = J^T A^-1 e + (z - J^T A^-1 J z)`` with ``A = J J^T + lambda^2 I``:
  damped least squares on the pose error, plus the redundancy step ``z`` projected
  into the Jacobian's null space;
* joints clipped to their limits, and the step length capped (``MAX_STEP_RAD``).

Redundancy. A 7-axis arm has a one-parameter family of joints per pose (the
elbow's swivel). The parameter is fixed by *holding* one joint (``hold_joint``,
the Panda's A3, the upper arm's rotation) at its value in the posture
``q_ref`` (the cell's home): the six other joints then solve a square problem,
damped Gauss-Newton converges in a few iterations, and the solution is a
smooth function of the pose, the same whatever the seed within a branch, so
neighbouring targets get neighbouring joints. Rows the held arm cannot reach
(the held value puts them beyond a limit) are solved with the joint free: the
least-squares step on the pose plus ``z = NULL_GAIN * W (q_ref - q)`` (``W`` the
inverse squared joint ranges) projected into the Jacobian's null space, which
slides the arm along its self-motion towards the posture, away from limits. A
row is done when the pose error is under ``TOL_M`` / ``TOL_RAD`` (and, free,
when the null-space step is under ``NULL_TOL_RAD``, or the iterations run out).

Seeding along a path: :meth:`BatchDLSIK.solve` solves row 0 from the
caller's seed, then every ``STRIDES[0]``-th row, every ``STRIDES[1]``-th, ...
and finally every row, each level starting from the joints interpolated
between the rows solved at the level before (a smooth path's joints are close
to that line, so Gauss-Newton needs one or two steps); rows that still fail
are retried from ``q_ref`` and from the seed, held, then free. Scattered
targets (:meth:`BatchDLSIK.solve_rows`, one start per row) are retried held
and free from ``q_ref``, then with plain damped least squares (no redundancy
step) from their own start and from ``RESTARTS`` fixed postures spread over
the joint ranges. A row whose error stops shrinking far from its pose
(``STALL_ITER``, ``STALL_M``: held by a limit) gives up early rather than use
all its iterations. Status codes are those of ``kinematics.py``:
``IK_OUT_OF_REACH`` (no convergence: the row then holds the previous row's
joints), ``IK_SINGULAR`` (smallest singular value of the Jacobian under
``SINGULAR_SIGMA``, metres).
"""
from __future__ import annotations

import numpy as np

from fabric.robot.joint_axes import JointAxes
from fabric.robot.kinematics import IK_OK, IK_OUT_OF_REACH, IK_SINGULAR

__all__ = ["BatchDLSIK", "STRIDES", "MAX_ITER"]

TOL_M = 1e-8                 # position error at convergence (10 nm)
TOL_RAD = 1e-8               # orientation error at convergence
NULL_TOL_RAD = 1e-5          # the redundancy step at convergence
MAX_ITER = 60                # iterations per attempt
RETRY_ITER = 120             # ... per retry from another start
DAMPING2 = 1e-10             # lambda^2 (m^2): damping of the least-squares step (the step is capped too)
NULL_GAIN = 0.5              # gain of the redundancy step
MAX_STEP_RAD = 0.4           # largest joint change per iteration
RESTARTS = 64                # further starts, spread over the joint ranges, for rows that still fail
STALL_ITER = 16              # a row whose pose error has not shrunk by 10 % in this many iterations ...
STALL_M = 1e-3               # ... while still over this (m, or rad) has stalled (against a limit): it stops
STRIDES = (4096, 256, 16)    # path rows solved level by level, each seeding the next, finer one
SINGULAR_SIGMA = 5e-3        # the Jacobian's smallest singular value (m / rad) under which a row is singular


def _spd_solve(J: np.ndarray, rhs: np.ndarray, damping2: float) -> np.ndarray:
    """Solve ``(J J^T + damping2 I) x = b`` per row for right-hand sides ``rhs`` (6, R, N); J (6, nq, N).

    Cholesky written out over the 6 x 6 entries, every operation one on (N,) rows
    (the batched ``np.linalg.solve`` costs several times more on many small matrices).
    """
    m, n = J.shape[0], J.shape[2]
    A = np.einsum("rin,cin->rcn", J, J)
    L = np.zeros((m, m, n))
    for r in range(m):
        for c in range(r + 1):
            acc = A[r, c] - np.einsum("kn,kn->n", L[r, :c], L[c, :c])
            if r == c:
                L[r, r] = np.sqrt(np.maximum(acc + damping2, 1e-300))
            else:
                L[r, c] = acc / L[c, c]
    y = np.empty_like(rhs)
    for r in range(m):
        y[r] = (rhs[r] - np.einsum("kn,kbn->bn", L[r, :r], y[:r])) / L[r, r]
    x = np.empty_like(rhs)
    for r in range(m - 1, -1, -1):
        x[r] = (y[r] - np.einsum("kn,kbn->bn", L[r + 1:, r], x[r + 1:])) / L[r, r]
    return x


def _interpolated_starts(rows: np.ndarray, known: np.ndarray, q_known: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """Starts (len(rows), nq) for path rows: joints interpolated between the solved rows ``known`` on each side
    (row index as the parameter), the last solved row after the end, the seed before the first."""
    if not len(known):
        return np.broadcast_to(seed, (len(rows), len(seed))).copy()
    out = np.empty((len(rows), len(seed)))
    for j in range(len(seed)):
        out[:, j] = np.interp(rows, known, q_known[:, j])
    out[rows < known[0]] = seed
    return out


def _skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


class BatchDLSIK:
    """Damped-least-squares IK of a serial revolute arm on many TCP poses at once (module docstring).

    ``axes`` the arm's joint axes at zero, ``tool_T`` flange -> TCP (mm),
    ``q_ref_rad`` the posture the redundancy is resolved towards (default: the
    middle of the joint ranges, each clipped to one turn).
    """

    batched = True            # path IK may hand it every row of a path at once

    def __init__(self, axes: JointAxes, lower_rad: np.ndarray, upper_rad: np.ndarray, tool_T: np.ndarray,
                 q_ref_rad: np.ndarray | None = None, hold_joint: int | None = None) -> None:
        if not axes.revolute.all():
            raise ValueError("batched DLS IK handles revolute joints only")
        self.nq = len(axes.directions)
        self.lower_rad = np.asarray(lower_rad, dtype=float).copy()
        self.upper_rad = np.asarray(upper_rad, dtype=float).copy()
        self.w = np.asarray(axes.directions, dtype=float)
        self.p_m = np.asarray(axes.points_mm, dtype=float) / 1000.0
        self.K = np.stack([_skew(w) for w in self.w])
        self.K2 = self.K @ self.K
        self.tool_T = np.asarray(tool_T, dtype=float)
        M = np.asarray(axes.flange_T, dtype=float) @ self.tool_T          # TCP at q = 0
        self.M = M.copy()
        self.M[:3, 3] /= 1000.0
        span = np.minimum(self.upper_rad, np.pi) - np.maximum(self.lower_rad, -np.pi)
        self.weight = 1.0 / np.maximum(span, 1e-3) ** 2
        self.weight /= self.weight.mean()
        mid = 0.5 * (np.maximum(self.lower_rad, -np.pi) + np.minimum(self.upper_rad, np.pi))
        self.q_ref = mid if q_ref_rad is None else np.asarray(q_ref_rad, dtype=float).copy()
        if hold_joint is not None and not 0 <= hold_joint < self.nq:
            raise ValueError(f"hold_joint {hold_joint} is not a joint of a {self.nq}-joint arm")
        self.hold = hold_joint
        rng = np.random.default_rng(20)            # fixed: the same targets always get the same joints
        self.restarts = rng.uniform(np.maximum(self.lower_rad, -np.pi), np.minimum(self.upper_rad, np.pi),
                                    (RESTARTS, self.nq))

    # Kinematics (rows last: every quantity is an array (..., N)) ---------------------
    def _chain(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """FK of joints ``q`` (nq, N): TCP rotation (3, 3, N), position (3, N) m, and the axis lines
        (nq, 3, N): directions and points (m).

        Joint i turns the rest of the arm about its current line: ``R <- R Rot(w_i, q_i)`` with
        ``Rot = I + s K + (1 - c) K^2`` (K the skew matrix of the axis at zero) and the translation
        ``t <- R (p_i - Rot p_i) + t`` (R before the joint).
        """
        n = q.shape[1]
        R = np.broadcast_to(np.eye(3)[:, :, None], (3, 3, n))
        t = np.zeros((3, n))
        ws = np.empty((self.nq, 3, n))
        ps = np.empty((self.nq, 3, n))
        eye = np.eye(3)[:, :, None]
        for i in range(self.nq):
            ws[i] = np.einsum("abn,b->an", R, self.w[i])
            ps[i] = np.einsum("abn,b->an", R, self.p_m[i]) + t
            Ri = eye + self.K[i][:, :, None] * np.sin(q[i]) + self.K2[i][:, :, None] * (1.0 - np.cos(q[i]))
            t = ps[i] - np.einsum("abn,bcn,c->an", R, Ri, self.p_m[i])
            R = np.einsum("abn,bcn->acn", R, Ri)
        Rt = np.einsum("abn,bc->acn", R, self.M[:3, :3])
        pt = np.einsum("abn,b->an", R, self.M[:3, 3]) + t
        return Rt, pt, ws, ps

    def fk(self, q_rad: np.ndarray) -> np.ndarray:
        """TCP poses (N, 4, 4) mm for joints (N, nq)."""
        q = np.atleast_2d(np.asarray(q_rad, dtype=float))
        R, p, _, _ = self._chain(np.ascontiguousarray(q.T))
        T = np.zeros((len(q), 4, 4))
        T[:, :3, :3] = R.transpose(2, 0, 1)
        T[:, :3, 3] = p.T * 1000.0
        T[:, 3, 3] = 1.0
        return T

    @staticmethod
    def _jacobian(p: np.ndarray, ws: np.ndarray, ps: np.ndarray) -> np.ndarray:
        """Geometric TCP Jacobian (6, nq, N): ``(w_i x (p - p_i), w_i)``, base frame."""
        J = np.empty((6, ws.shape[0], ws.shape[2]))
        J[:3] = np.cross(ws, p[None] - ps, axis=1).transpose(1, 0, 2)
        J[3:] = ws.transpose(1, 0, 2)
        return J

    # IK -------------------------------------------------------------------
    def iterate(self, R_goal: np.ndarray, p_goal_m: np.ndarray, q0: np.ndarray,
                max_iter: int = MAX_ITER, held: bool = False, pull: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Joints (N, nq) and convergence (N,) from starts ``q0`` (N, nq); only unconverged rows iterate.

        A row converges when its pose error is under tolerance and its redundancy step has settled
        (under ``NULL_TOL_RAD``); a row whose pose is met but whose redundancy step is still moving at
        ``max_iter`` (held by a limit) counts as converged too. ``held``: the joint ``hold`` stays at
        its ``q_ref`` value and the others solve the pose alone (a square problem: no redundancy step);
        ``pull`` False: no redundancy step either (plain damped least squares from the start given).
        """
        q_all = np.ascontiguousarray(np.clip(np.array(q0, dtype=float), self.lower_rad, self.upper_rad).T)
        free = np.arange(self.nq)
        if held and self.hold is not None:
            q_all[self.hold] = self.q_ref[self.hold]
            free = free[free != self.hold]
        gain = 0.0 if (held and self.hold is not None) or not pull else NULL_GAIN
        Rg_all = np.ascontiguousarray(R_goal.transpose(1, 2, 0))
        pg_all = np.ascontiguousarray(p_goal_m.T)
        n = q_all.shape[1]
        done = np.zeros(n, dtype=bool)
        met = np.zeros(n, dtype=bool)
        act = np.arange(n)
        lo, hi = self.lower_rad[:, None], self.upper_rad[:, None]
        err_then = np.full(n, np.inf)               # each row's pose error STALL_ITER iterations ago
        for it in range(max_iter):
            if not len(act):
                break
            q = q_all[:, act]
            R, p, ws, ps = self._chain(q)
            e = np.empty((6, len(act)))
            e[:3] = pg_all[:, act] - p
            e[3:] = 0.5 * np.cross(R, Rg_all[:, :, act], axis=0).sum(axis=1)   # 1/2 sum_k r_k x r*_k
            J = self._jacobian(p, ws, ps)[:, free]
            z = gain * self.weight[free, None] * (self.q_ref[free, None] - q[free])
            rhs = np.stack([e, np.einsum("rin,in->rn", J, z)], axis=1)          # (6, 2, N)
            x = _spd_solve(J, rhs, DAMPING2)
            dq = np.einsum("rin,rn->in", J, x[:, 0])
            dn = z - np.einsum("rin,rn->in", J, x[:, 1])
            ep2, er2 = np.einsum("an,an->n", e[:3], e[:3]), np.einsum("an,an->n", e[3:], e[3:])
            pose_ok = (ep2 < TOL_M ** 2) & (er2 < TOL_RAD ** 2)
            ok = pose_ok & (np.max(np.abs(dn), axis=0) < NULL_TOL_RAD)
            met[act] = pose_ok
            stop = ok.copy()
            if it % STALL_ITER == 0:                   # rows stuck far from their pose stop here, unsolved
                err = np.sqrt(np.maximum(ep2, er2))
                stop |= (err > STALL_M) & (err > 0.9 * err_then[act])
                err_then[act] = err
            done[act[ok]] = True
            dq += dn
            big = np.max(np.abs(dq), axis=0)
            dq *= np.minimum(1.0, MAX_STEP_RAD / np.maximum(big, 1e-300))
            q_new = q.copy()
            q_new[free] = np.clip(q[free] + dq, lo[free], hi[free])
            keep = ~stop
            q_all[:, act[keep]] = q_new[:, keep]
            act = act[keep]
        done |= met
        return np.ascontiguousarray(q_all.T), done

    def pose_error(self, R_goal: np.ndarray, p_goal_m: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and orientation (rad) error norms (N,) of joints ``q`` against the goals."""
        T = self.fk(q)
        ep = np.linalg.norm(p_goal_m - T[:, :3, 3] / 1000.0, axis=1)
        er = np.linalg.norm(0.5 * np.cross(T[:, :3, :3].transpose(0, 2, 1), R_goal.transpose(0, 2, 1)).sum(axis=1),
                            axis=1)
        return ep, er

    def solve_rows(self, T_tcp_mm: np.ndarray, q0_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Joints (N, nq) and status (N,) of scattered targets, each from its own start ``q0_rad`` (N, nq), with the
        retries of the module docstring (a row not solved keeps the joints its last attempt ended at)."""
        T = np.asarray(T_tcp_mm, dtype=float).reshape(-1, 4, 4)
        q0 = np.asarray(q0_rad, dtype=float).reshape(len(T), self.nq)
        R_goal, p_goal = T[:, :3, :3], T[:, :3, 3] / 1000.0
        q, ok = self.iterate(R_goal, p_goal, q0, held=True)
        self._retry(R_goal, p_goal, q, ok, [self.q_ref], held=True)
        self._retry(R_goal, p_goal, q, ok, [self.q_ref])
        self._retry(R_goal, p_goal, q, ok, [q0, *self.restarts], pull=False)
        return q, self._status(R_goal, p_goal, q, ok)

    def _retry(self, R_goal: np.ndarray, p_goal: np.ndarray, q: np.ndarray, ok: np.ndarray,
               starts: list[np.ndarray], held: bool = False, pull: bool = True) -> None:
        """Rows not converged (``ok`` False) tried again from each start in turn; ``q``, ``ok`` updated in place."""
        for start in starts:
            if ok.all():
                return
            bad = np.flatnonzero(~ok)
            begin = start[bad] if start.ndim == 2 else np.broadcast_to(start, (len(bad), self.nq))
            q2, ok2 = self.iterate(R_goal[bad], p_goal[bad], begin, RETRY_ITER, held, pull)
            q[bad[ok2]], ok[bad[ok2]] = q2[ok2], True

    def solve(self, T_tcp_mm: np.ndarray, q_seed: np.ndarray, retry: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Joints (N, nq) and status (N,) uint8 for TCP poses (N, 4, 4) mm, seeded along the rows (module doc).

        ``retry`` False: rows that fail from the path's own starts are left failed (a quick feasibility
        test, e.g. of candidate nozzle rotations) instead of being tried again from other postures."""
        T = np.asarray(T_tcp_mm, dtype=float).reshape(-1, 4, 4)
        seed = np.asarray(q_seed, dtype=float).reshape(self.nq)
        n = len(T)
        if n == 0:
            return np.zeros((0, self.nq)), np.zeros(0, dtype=np.uint8)
        R_goal, p_goal = T[:, :3, :3], T[:, :3, 3] / 1000.0
        rows = np.zeros(1, dtype=np.intp)             # solved so far: row 0 from the seed, then finer levels
        q_rows, ok_rows = self.iterate(R_goal[:1], p_goal[:1], seed[None], held=True)
        for stride in (*STRIDES, 1):
            level = np.arange(0, n, stride)
            starts = _interpolated_starts(level, rows[ok_rows], q_rows[ok_rows], seed)
            q_rows, ok_rows = self.iterate(R_goal[level], p_goal[level], starts, held=True)
            rows = level
        q, ok = q_rows, ok_rows
        if retry:
            self._retry(R_goal, p_goal, q, ok, [self.q_ref, seed], held=True)
            self._retry(R_goal, p_goal, q, ok, [self.q_ref, seed])
        status = self._status(R_goal, p_goal, q, ok)
        if not ok.all():                                   # unreachable rows hold the previous row's joints
            idx = np.maximum.accumulate(np.where(ok, np.arange(n), -1))
            q = np.where((idx >= 0)[:, None], q[np.maximum(idx, 0)], seed)
        return q, status

    def _status(self, R_goal: np.ndarray, p_goal: np.ndarray, q: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """IK status per row: out of reach where not converged, singular where the Jacobian nearly loses rank."""
        status = np.where(ok, IK_OK, IK_OUT_OF_REACH).astype(np.uint8)
        rows = np.flatnonzero(ok)
        if len(rows):
            _, p, ws, ps = self._chain(np.ascontiguousarray(q[rows].T))
            J = self._jacobian(p, ws, ps)                                       # (6, nq, M)
            JJ = np.einsum("rin,cin->nrc", J, J)                               # its smallest singular value is
            sigma = np.sqrt(np.maximum(np.linalg.eigvalsh(JJ)[:, 0], 0.0))    # sqrt(smallest eigenvalue of J J^T)
            status[rows[sigma < SINGULAR_SIGMA]] = IK_SINGULAR
        return status
