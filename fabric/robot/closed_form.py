"""Branch selection and the closed-form IK solver over any closed-form arm family (``arm_family.ClosedFormArm``).

See ``fabric/robot/kinematics.py`` for the branch-selection argument and the
singularity holds, and ``opw.py`` / ``ur.py`` / ``panda.py`` / ``kinematics.py``
for the geometry of each family; this module holds the solver that applies
them to (N, 4, 4) TCP poses within joint limits, with joint continuity along
the rows. Internally a pose is the nine numbers the IK reads (the arm's
end-frame position, z and y axes, ``pose_cols``) and joints are per-joint rows
(nq, N): contiguous arrays. The end frame is the flange for the IRB 140
reference model; other families map it to the URDF flange with
``arm.flange_T``, folded into the TCP -> end-frame transform
:attr:`ClosedFormIK.tool_inv_T`.

A redundant family (the 7-axis Panda type) takes one joint as a parameter
(``arm.free_joint``, A7): every call may give its value per row (``q_free``),
else it is held at :attr:`ClosedFormIK.free_rad` (the cell's home value, set
by ``RobotModel.set_posture``); ``panda.py`` says why holding it loses nothing
for printing.
"""
from __future__ import annotations

import numpy as np

from fabric.robot.arm_family import ClosedFormArm
from fabric.robot.kinematics import (
    IK_JOINT_LIMIT,
    IK_OK,
    IK_OUT_OF_REACH,
    IK_SINGULAR,
    LIMIT_TOL_RAD,
    PI,
    TWO_PI,
    multi_turn_mask,
    pose_cols,
    wrap,
    wrap_diff,
)
from fabric.robot.native_track import NativeTrack

__all__ = ["ClosedFormIK", "select_branches"]


def _sq_dist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Squared joint distance, every angle compared modulo 2*pi (last axis = joints)."""
    d = wrap(a - b)
    return np.einsum("...j,...j->...", d, d)


def select_branches(qb: np.ndarray, allowed: np.ndarray, q_seed: np.ndarray,
                    quiet: np.ndarray | None = None) -> np.ndarray:
    """Branch index (N,) per row: the allowed branch nearest the previous row's choice.

    ``qb`` (N, B, nq) candidates, ``allowed`` (N, B) the candidates a row may
    take (a row with none keeps its predecessor's index). ``quiet`` (N,) marks
    rows known to keep every allowed branch (see module docstring); rows not
    marked get the full B x B distance test.
    """
    n, nb, _ = qb.shape
    d0 = np.where(allowed[0], _sq_dist(qb[0], np.asarray(q_seed, dtype=float)), np.inf)
    marks = np.full(n, -1, dtype=np.intp)
    marks[0] = int(np.argmin(d0)) if allowed[0].any() else 0
    if n > 1:
        check = np.arange(1, n) if quiet is None else np.flatnonzero(~quiet[1:]) + 1
        eye = np.arange(nb)
        rows, nxts = [], []
        for s in range(0, len(check), 4096):            # bounded memory: 4096 x B x B x nq
            idx = check[s:s + 4096]
            d = _sq_dist(qb[idx][:, None, :, :], qb[idx - 1][:, :, None, :])
            al = allowed[idx]
            best = np.argmin(np.where(al[:, None, :], d, np.inf), axis=2)
            best[~al.any(axis=1)] = eye
            moving = (best != eye).any(axis=1)
            rows.append(idx[moving])
            nxts.append(best[moving])
        b = int(marks[0])
        if rows:
            for i, row in zip(np.concatenate(rows).tolist(), np.concatenate(nxts).tolist(), strict=True):
                b = row[b]
                marks[i] = b
    idx = np.maximum.accumulate(np.where(marks >= 0, np.arange(n), 0))
    return marks[idx]


class ClosedFormIK:
    """Closed-form IK of a ``ClosedFormArm`` (OPW, UR, Panda, the IRB 140 reference) within joint limits (mm)."""

    max_rows = 65536          # bound on rows per vectorised step (memory: max_rows x 8 x nq floats)
    tracking = True           # False: always the full 8-branch method (reference for tests)
    use_native = True         # False: numpy's tracking even where the C helper could answer (reference for tests)

    def __init__(self, arm: ClosedFormArm, lower_rad: np.ndarray, upper_rad: np.ndarray,
                 tool_T: np.ndarray | None = None, free_rad: float | None = None) -> None:
        self.arm = arm
        self.family = arm.family
        self.nq = int(arm.nq)
        self.free_joint = arm.free_joint
        self.lower_rad = np.asarray(lower_rad, dtype=float)
        self.upper_rad = np.asarray(upper_rad, dtype=float)
        self.multi = multi_turn_mask(self.lower_rad, self.upper_rad)
        self.tool_T = np.eye(4) if tool_T is None else np.asarray(tool_T, dtype=float)
        F = np.asarray(arm.flange_T, dtype=float)
        self._end_inv = None if np.array_equal(F, np.eye(4)) else _inv_T(F)     # flange -> end frame
        self._tool_inv = _inv_T(F @ self.tool_T)
        self._native: list[NativeTrack | None] = []      # the C tracking, looked up at the first solve
        self.free_rad = 0.0                # the redundancy joint's value when a call gives none
        if self.free_joint is not None:
            j = self.free_joint
            mid = 0.5 * (max(self.lower_rad[j], -PI) + min(self.upper_rad[j], PI))
            self.free_rad = float(mid if free_rad is None else free_rad)

    def _free(self, q_free: float | np.ndarray | None, n: int) -> float | np.ndarray | None:
        """The redundancy joint's values for ``n`` rows (None for a 6-axis arm): ``q_free`` or the held value."""
        if self.free_joint is None:
            return None
        if q_free is None:
            return self.free_rad
        if np.ndim(q_free) == 0:
            return float(q_free)
        v = np.asarray(q_free, dtype=float).reshape(-1)
        if len(v) != n:
            raise ValueError(f"q_free needs one value per row ({n}), got {len(v)}")
        return v

    def fk_flange(self, q_rad: np.ndarray) -> np.ndarray:
        """Flange poses for joints (N, nq) or (nq,)."""
        return self.arm.fk_flange(q_rad)

    @property
    def tool_inv_T(self) -> np.ndarray:
        """TCP -> arm end frame (``inv(flange_T @ tool_T)``; TCP -> flange when the end frame is the flange)."""
        return self._tool_inv

    def wrist_sin(self, q_rad: np.ndarray) -> np.ndarray:
        """The family's distance from its wrist singularity (``|sin|`` of the wrist bend) for joints (N, nq)."""
        return self.arm.wrist_sin(np.asarray(q_rad, dtype=float).T)

    def canon(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Put single-turn joints of q (..., nq), angles in [-pi, pi], in ``[lower, lower + 2*pi)``.

        That representation is unique for a range under a turn; returns q
        (modified in place) and the in-limits mask (...,). Multi-turn joints
        stay in [-pi, pi] and are placed by unwrapping along the path.
        """
        inlim = np.ones_like(q[..., 0], dtype=bool)        # in q's own memory order (the families return views)
        for j in np.flatnonzero(~self.multi).tolist():
            inlim &= self._canon_col(j, q[..., j])
        return q, inlim

    def _canon_col(self, j: int, col: np.ndarray) -> np.ndarray:
        """:meth:`canon` of joint ``j``'s angles ``col`` (in place); returns its in-limits mask.

        Both ends take the limit tolerance: an angle a rounding error below the lower limit stays there (in
        limits) instead of turning a full turn up past the upper one. Without it, a configuration at a limit
        (a path clipped to it, the wrist flip of one at the opposite limit) was in or out by the last bit of
        an ``atan2``, which differs between numpy's kernels on different CPUs.
        """
        lo, tol = self.lower_rad[j], LIMIT_TOL_RAD
        if lo > -PI:                                   # (ufuncs with where=: no index arrays, views stay views)
            np.add(col, TWO_PI, out=col, where=col < lo - tol)
        elif lo + TWO_PI <= PI:
            np.subtract(col, TWO_PI, out=col, where=col >= lo + TWO_PI - tol)
        return (col >= lo - tol) & (col <= self.upper_rad[j] + tol)

    def branches(self, T_flange: np.ndarray, q1_hold: np.ndarray | None = None,
                 q_free: float | np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The 8 branches in limit representation: ``q (N, 8, nq), ok, reach, singular`` (N, 8)."""
        return self.branches_cols(pose_cols(T_flange, self._end_inv), q1_hold, q_free)

    def branches_cols(self, C: np.ndarray, q1_hold: np.ndarray | None = None,
                      q_free: float | np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`branches` of end-frame poses given as columns (9, N) (``fabric.robot.kinematics.pose_cols``)."""
        qb, reach, sing = self.arm.ik_branches_cols(C, q1_hold, self._free(q_free, C.shape[1]))
        qb, inlim = self.canon(qb)
        return qb, reach & inlim, reach, sing

    def ik_flange(self, T_flange: np.ndarray, q_seed: np.ndarray, q_free: float | np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Joints (N, nq) and status (N,) uint8 for flange poses (N, 4, 4), continuous from ``q_seed``."""
        return self.ik_cols(pose_cols(T_flange, self._end_inv), q_seed, q_free)

    def solve(self, T_tcp_mm: np.ndarray, q_seed: np.ndarray, q_free: float | np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
        """As :meth:`ik_flange` for TCP poses (``tool_T`` removed while gathering the columns).

        The solver interface shared with :class:`fabric.robot.numeric.NumericIK`."""
        return self.ik_cols(pose_cols(T_tcp_mm, self._tool_inv), q_seed, q_free)

    def ik_cols(self, C: np.ndarray, q_seed: np.ndarray, q_free: float | np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
        """As :meth:`ik_flange` for end-frame poses given as columns ``C`` (9, N): position, z, y axes.

        ``q_free``: a redundant arm's parameter joint per row ((N,) or one value; default :attr:`free_rad`).
        Everything runs on contiguous per-joint rows (nq, N); the result is
        transposed to (N, nq) once at the end.
        """
        nq = self.nq
        seed = np.asarray(q_seed, dtype=float).reshape(nq)
        C = np.asarray(C, dtype=float)
        n = C.shape[1]
        free = self._free(q_free, n)
        q = np.empty((nq, n))
        row_ok, reach_any, sing = (np.empty(n, dtype=bool) for _ in range(3))
        fast = self.native_track()
        if fast is None or not fast.track(C, seed, self.max_rows, q, row_ok, reach_any, sing, free):
            q1, degen = self.arm.q1_free(C)                # A1 undefined (wrist centre on its axis): hold it
            hold = _forward_fill(q1, ~degen, seed[0]) if degen.any() else None
            self._track(C, hold, free, seed, q, row_ok, reach_any, sing)
        wdeg = reach_any & sing                             # one wrist angle free (a subset of the singular
        if wdeg.any():                                      # rows): hold it, solve the rest
            cand = np.flatnonzero(wdeg)
            wdeg[cand] = self.arm.wrist_degenerate(q[:, cand])
        if wdeg.any():
            sel = np.flatnonzero(wdeg)
            held = np.stack([_forward_fill(q[j], ~wdeg, seed[j])[sel] for j in range(nq)])
            q[:, sel] = self.arm.resolve_wrist(C[:, sel], q[:, sel], held)
        if not reach_any.all():                           # unreachable rows hold the previous joints
            for j in range(nq):
                q[j] = _forward_fill(q[j], reach_any, seed[j])
        self._place_multi_turn(q, seed)
        status = np.full(n, IK_OK, dtype=np.uint8)
        if not row_ok.all() or sing.any():
            status[sing & row_ok] = IK_SINGULAR
            status[~row_ok & reach_any] = IK_JOINT_LIMIT
            status[~reach_any] = IK_OUT_OF_REACH
        return np.ascontiguousarray(q.T), status

    def native_track(self) -> NativeTrack | None:
        """:meth:`_track` in C for this arm (``fabric.robot.native_track``), or None: numpy's path answers."""
        if not self.tracking or not self.use_native:
            return None
        if not self._native:
            self._native.append(NativeTrack.of(self.arm, self.lower_rad, self.upper_rad, self.multi))
        return self._native[0]

    def _track(self, C: np.ndarray, hold: np.ndarray | None, free: float | np.ndarray | None, seed: np.ndarray,
               q: np.ndarray, row_ok: np.ndarray, reach_any: np.ndarray, sing: np.ndarray) -> None:
        """Fill the chosen branch's solution per row into ``q`` (nq, N) (module docstring: branch choice).

        Alternates two vectorised modes. *Tracking*: solve only the current
        branch for a block of rows and accept the leading rows where it stays
        valid and quiet (step < half the distance to any other branch: then it
        is provably the nearest). *Full*: at the first row that fails, solve all
        8 branches over a window and run :func:`select_branches`. Windows grow
        while tracking keeps failing at once (scattered targets), so the cost
        stays that of the full method in the worst case and ~1/4 of it on paths.
        """
        n = C.shape[1]
        i, b, prev = 0, -1, seed
        window, block = 32, 2048
        single = np.flatnonzero(~self.multi).tolist()
        while i < n:
            if b < 0 or not self.tracking:
                j = min(n, i + (window if self.tracking else self.max_rows))
                qb, ok, reach, sg = self.branches_cols(C[:, i:j], None if hold is None else hold[i:j],
                                                       _rows(free, i, j))
                allowed = np.where(ok.any(axis=1, keepdims=True), ok, reach)
                bidx = select_branches(qb, allowed, prev, self._quiet(qb, allowed))
                r = np.arange(j - i)
                q[:, i:j] = qb[r, bidx].T
                row_ok[i:j], sing[i:j] = ok[r, bidx], sg[r, bidx]
                reach_any[i:j] = reach.any(axis=1)
                b = int(bidx[-1]) if ok[-1, bidx[-1]] else -1
                window = min(self.max_rows, window * 2) if b < 0 else window
                prev, i = q[:, j - 1].copy(), j
                continue
            j = min(n, i + block)
            qt, reach_t, sg, gap = self.arm.ik_branch_cols(C[:, i:j], b, None if hold is None else hold[i:j],
                                                           _rows(free, i, j))
            fine = reach_t
            for jj in single:
                fine &= self._canon_col(jj, qt[jj])
            d = np.diff(qt, axis=1, prepend=prev[:, None])
            sep2 = np.minimum(gap, PI) ** 2
            quiet = 4.0 * np.einsum("ji,ji->i", d, d) < sep2      # unwrapped steps: all < pi/2 if it passes
            loud = np.flatnonzero(~quiet)
            if len(loud):                                        # compare those modulo 2*pi
                dw = wrap(d[:, loud])
                quiet[loud] = 4.0 * np.einsum("ji,ji->i", dw, dw) < sep2[loud]
            fine &= quiet
            f = int(np.argmin(fine)) if not fine.all() else j - i
            q[:, i:i + f], sing[i:i + f] = qt[:, :f], sg[:f]
            row_ok[i:i + f] = True
            reach_any[i:i + f] = True
            if f:
                prev = qt[:, f - 1].copy()
            i += f
            if i < j:                                      # switch to the full method at row i
                b = -1
                window = 32 if f >= 256 else min(self.max_rows, window * 4)
                block = 2048
            else:
                block = min(self.max_rows, block * 2)

    def _quiet(self, qb: np.ndarray, allowed: np.ndarray) -> np.ndarray:
        """Rows where every allowed branch's nearest successor is itself (module docstring).

        The separation between branches is bounded below by pi (the wrist flip
        turns A4 of a spherical wrist, A6 of a UR arm, by pi), the A3 distance between
        the two elbows of a shoulder, and the A1 distance between the two
        shoulders (pi for the IRB 140, less for an OPW arm with b != 0 or a UR arm).
        """
        n = len(qb)
        quiet = np.zeros(n, dtype=bool)
        if n < 2:
            return quiet
        same = np.all(allowed[1:] == allowed[:-1], axis=1)
        if self.family == "panda":
            sep = self._panda_separation(qb[1:], allowed[1:])
            step2 = _sq_dist(qb[1:], qb[:-1])
            max_step2 = np.max(np.where(allowed[1:], step2, 0.0), axis=1)
            quiet[1:] = same & (4.0 * max_step2 < sep * sep)
            return quiet
        if self.family != "ur":          # spherical wrists: the wrist flip moves by exactly its partner's step
            step2 = _sq_dist(qb[1:, ::2, :], qb[:-1, ::2, :])
            step_allowed = allowed[1:, ::2] | allowed[1:, 1::2]
        else:
            step2 = _sq_dist(qb[1:], qb[:-1])
            step_allowed = allowed[1:]
        max_step2 = np.max(np.where(step_allowed, step2, 0.0), axis=1)
        pair_allowed = allowed[1:, ::2] | allowed[1:, 1::2]
        sep = np.full(n - 1, PI)
        # the two elbows of a shoulder: one A3 gap for a spherical wrist; a UR arm's wrist choice moves its arm
        # plane, so each wrist has its own pair of elbows (their A3 far apart under one wrist, close under the
        # other near a stretched elbow)
        for s, w in ((0, 0), (0, 1), (1, 0), (1, 1)) if self.family == "ur" else ((0, 0), (1, 0)):
            a, c = 4 * s + w, 4 * s + 2 + w
            gap = np.abs(wrap_diff(qb[1:, a, 2] - qb[1:, c, 2]))
            both = (allowed[1:, a] & allowed[1:, c]) if self.family == "ur" else \
                (pair_allowed[:, 2 * s] & pair_allowed[:, 2 * s + 1])
            sep = np.where(both, np.minimum(sep, gap), sep)
        if self.family != "abb-spherical-wrist":         # the reference model's shoulders are pi apart
            gap = np.abs(wrap_diff(qb[1:, 0, 0] - qb[1:, 4, 0]))
            both = (pair_allowed[:, 0] | pair_allowed[:, 1]) & (pair_allowed[:, 2] | pair_allowed[:, 3])
            sep = np.where(both, np.minimum(sep, gap), sep)
        quiet[1:] = same & (4.0 * max_step2 < sep * sep)
        return quiet

    @staticmethod
    def _panda_separation(qb: np.ndarray, allowed: np.ndarray) -> np.ndarray:
        """A lower bound (N,) on the distance between any two allowed branches of a Panda-type arm (``panda.py``).

        A4 depends on the elbow alone, so branches of different elbows are at least their A4 distance apart;
        A5 and A6 depend on the elbow and the wrist, so the two wrists of one elbow are at least the larger of
        their A5 and A6 distances apart; the two shoulders of one elbow and wrist are pi apart in A1.
        """
        sep = np.full(len(qb), PI)
        elbow = [allowed[:, [2 * e, 2 * e + 1, 2 * e + 4, 2 * e + 5]].any(axis=1) for e in range(2)]
        gap = np.abs(wrap_diff(qb[:, 0, 3] - qb[:, 2, 3]))
        sep = np.where(elbow[0] & elbow[1], np.minimum(sep, gap), sep)
        for e in range(2):
            w0 = allowed[:, 2 * e] | allowed[:, 2 * e + 4]
            w1 = allowed[:, 2 * e + 1] | allowed[:, 2 * e + 5]
            gap = np.maximum(np.abs(wrap_diff(qb[:, 2 * e, 4] - qb[:, 2 * e + 1, 4])),
                             np.abs(wrap_diff(qb[:, 2 * e, 5] - qb[:, 2 * e + 1, 5])))
            sep = np.where(w0 & w1, np.minimum(sep, gap), sep)
        return sep

    def _place_multi_turn(self, q: np.ndarray, seed: np.ndarray) -> None:
        """Unwrap multi-turn joints (rows of q (6, N)) from the seed on, then shift any wind-up back into limits.

        Works on integer turn counts (exact) and adds ``2*pi*turns`` to the
        wrapped angle once, so long paths that wind a joint many times before
        being shifted back lose no precision. Only rows that step by more than
        pi (a wrap) or leave the limits are touched.
        """
        fast = self.native_track()
        for j in np.flatnonzero(self.multi):
            if fast is not None:
                fast.place_multi_turn(q[j], float(seed[j]), float(self.lower_rad[j]), float(self.upper_rad[j]))
                continue
            raw = q[j]
            d = np.diff(raw, prepend=seed[j])
            wraps = np.flatnonzero(np.abs(d) > 0.999 * PI)          # superset of rint(d / 2pi) != 0
            lo, hi = self.lower_rad[j], self.upper_rad[j]
            if len(wraps):
                step = np.zeros(len(raw))
                step[wraps] = -np.rint(d[wraps] / TWO_PI)
                turns = np.cumsum(step)
                col = raw + TWO_PI * turns
            else:
                turns, col = None, raw
            over, under = col > hi + LIMIT_TOL_RAD, col < lo - LIMIT_TOL_RAD
            if over.any() or under.any():
                turns = np.zeros(len(raw)) if turns is None else turns
                turns -= np.where(over, np.ceil((col - hi) / TWO_PI), 0.0)
                turns += np.where(under, np.ceil((lo - col) / TWO_PI), 0.0)
            if turns is not None:
                q[j] = raw + TWO_PI * turns


def _rows(free: float | np.ndarray | None, i: int, j: int) -> float | np.ndarray | None:
    """Rows ``i:j`` of a per-row parameter (a single value or None stands for every row)."""
    return free[i:j] if isinstance(free, np.ndarray) else free


def _inv_T(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (4, 4)."""
    R = T[:3, :3].T
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R, -R @ T[:3, 3]
    return out


def _forward_fill(values: np.ndarray, valid: np.ndarray, first: float) -> np.ndarray:
    """Replace invalid entries by the last valid one before them (``first`` before any)."""
    idx = np.maximum.accumulate(np.where(valid, np.arange(len(values)), -1))
    return np.where(idx >= 0, values[np.maximum(idx, 0)], first)
