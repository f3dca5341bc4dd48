"""Closed-form, vectorised kinematics of Panda-type 7-axis arms with A7 as the redundancy parameter: 8 branches per A7.

The model and its parameters are those of ``panda_derive.py``: the axes at
zero in a model base with the shoulder point ``S`` at the origin, axis 1 along
z and axis 2 along y; joint i turns the rest of the arm about its line at zero
(product of exponentials). This is the geometric solver of He & Liu 2021
("Analytical Inverse Kinematics for Franka Emika Panda - a Geometrical Solver
for 7-DOF Manipulators with Unconventional Design"), written with the joint
axes instead of a DH table and vectorised over rows and branches.

Inverse kinematics, per target (end frame ``E``: origin ``p``, axes ``x, y, z``
in the model base) **and a given A7**:

1. Undoing A7 turns the end frame back by ``-q7`` about its z axis (axis 7), so
   link 6 is known: its frame ``R6 = [x' y' z] K`` with ``x' = c7 x - s7 y``,
   ``y' = s7 x + c7 y`` and ``K`` constant, and the wrist point
   ``W = p + [x' y' z] kW`` (where axes 5 and 6 meet).
2. The shoulder-elbow-wrist triangle: ``|W - S|`` depends on A4 alone (S is
   fixed to links 0-3, W to links 4-6), ``|W|^2 = D - 2 R4 cos(q4 - g4)``, so
   ``q4 = g4 +- phi`` with ``cos phi = (D - |W|^2) / (2 R4)``: the elbow choice.
3. The wrist (Paden-Kahan subproblem 2): with A4 known, the shoulder point as
   seen from link 6, ``v = -R6^T W``, and from link 4 turned back by A4, ``u``
   (constant vectors combined with cos and sin of A4), are related by
   ``RotY(-q6) RotX(-q5) u = v`` in the basis ``(w5, w6, w5 x w6)``; the
   intermediate vector is ``(u_a, v_b, +-g)`` with ``g^2 = |u|^2 - u_a^2 - v_b^2``:
   the wrist choice, then q5 and q6 from one atan2 each.
4. The shoulder is spherical: ``R3 = RotZ(q1) RotY(q2 + beta) RotZ(q3) RotY(-beta)``
   is what remains, read off the upper arm direction ``d = R3 w3`` (``q1 =
   atan2(d_y, d_x)`` or turned by pi over the top: the shoulder choice,
   ``q2 + beta = atan2(+-|d_xy|, d_z)``) and ``m = R3 y``, which gives q3.

Branches are ``b = 4 * shoulder + 2 * elbow + wrist`` as in every family.
No trigonometric call but the atan2 of each angle (and cos, sin of the given
A7): cos and sin of q5, q6 and q1 come from the atan2's own arguments, and
the second shoulder is the first turned over the top, ``(q1 + pi, -q2 -
2 beta, q3 + pi)``. The Panda's A4 range (-176..-4 deg) lies mostly on one
side of the stretched elbow (A4 = -26.7 deg), so for most targets only the 4
branches of one elbow are within limits; the other elbow (A4 between -26.7
and -4 deg: the forearm bent slightly backwards) is kept so that every
configuration within the limits is found.

Singular rows (flagged, the exact solution is still returned): the elbow
stretched or folded (``sin phi < ELBOW_SING_COS``), the two wrist solutions
meeting (``g < WRIST_SING_SIN |W|``: the shoulder point in the plane of axes 5
and 6, where their rates grow without bound) and the shoulder's gimbal lock
(axes 1 and 3 aligned, ``|sin(q2 + beta)| < WRIST_SING_SIN``: the Panda's
spherical joint is its shoulder). Where one angle is exactly free (axes 1 and
3 aligned: only q1 + q3 is defined; or, on other arms of the family, the
shoulder point on axis 5 or on axis 6, which the Panda's A4 range excludes)
the solver holds it at the previous row's value and re-solves the rest
(:meth:`PandaArm.resolve_wrist`), as for a spherical wrist at q5 = 0.
Branches differ by ``2 phi`` in A4 (elbow), by ``2 atan2(g, |u_a|)`` in A6 and
``2 atan2(g, |v_b|)`` in A5 (wrist) and by pi in A1 (shoulder): the ``gap``
the solver's continuity test needs.

Why A7 is the parameter, and why holding it loses nothing for printing.
A 7-axis arm has a one-parameter family of joints per flange pose (the
elbow's swivel); given A7 the flange pose fixes link 6 and the rest is
finite, so A7 is a natural parameter (He & Liu). A printing tool whose nozzle
lies along axis 7 (the Panda cell's TCP is 150 mm along the flange z axis,
which is axis 7) fixes only 5 degrees of freedom: the nozzle's position and
direction. The free rotation ``theta`` about the nozzle that the planner
searches (``path_ik.py``) then turns the flange about axis 7, and the link-6
pose depends on ``theta - q7`` only. So with A7 held at any value within its
limits, sweeping theta reaches every link-6 pose, hence every solution of
A1..A6, that any (theta, A7) pair reaches: the elbow's swivel is exactly what
theta explores, and A7 only spins the nozzle about itself. Holding A7 at the
cell's home value (or at a value chosen per path, smooth and away from its
limits) and letting the planner choose theta therefore covers every
solution; A7 stays an explicit per-row input (``q_free``) so other strategies
can set it. With a tool off axis 7 the argument does not hold and A7 should
be chosen with the pose. Two limits of the argument in practice: the planner
tries theta on a grid (15 deg steps, one value per path where it can), so
"every solution" is up to that grid; and with A7 held, the upper arm passing
through vertical (A2 = 0) is a true singularity of the six other joints
though not of the 7-axis arm, so the planner keeps to swivels that avoid it
(on the Panda cell the arm's plane posture, A1 = A3 = 0, meets it above part
of the plate and a swivelled posture is chosen).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fabric.robot.arm_family import cols_in_frame, stack_branches
from fabric.robot.kinematics import ELBOW_SING_COS, WRIST_SING_SIN, flip, wrap
from fabric.robot.panda_derive import PandaParams

__all__ = ["PandaArm"]

FREE_SIN = 1e-9               # |sin| (or share of |W - S|) under which an angle is free: held, the rest re-solved

_Vec = tuple[np.ndarray, np.ndarray, np.ndarray]
_Num = float | np.ndarray


def _lin(vectors: tuple[_Vec, ...], coefs: np.ndarray) -> _Vec:
    """``sum_k coefs[k] * vectors[k]`` for 3-vectors of rows; zero coefficients are skipped and +-1 costs no
    product (the Panda's constant frames are signed permutations)."""
    out: list[np.ndarray | None] = [None, None, None]
    for vec, c in zip(vectors, coefs.tolist(), strict=True):
        if c == 0.0:
            continue
        for i in range(3):
            term = vec[i] if c == 1.0 else (-vec[i] if c == -1.0 else c * vec[i])
            cur = out[i]
            out[i] = term if cur is None else cur + term
    zero = np.zeros_like(vectors[0][0])
    return tuple(zero if o is None else o for o in out)          # type: ignore[return-value]


def _dot(a: _Vec, b: _Vec) -> np.ndarray:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


class _Link6(NamedTuple):
    """Step 1 and what depends on the target alone: link 6's frame columns, the wrist point and ``v``."""

    R6: tuple[_Vec, _Vec, _Vec]
    W: _Vec
    WW: np.ndarray             # |W - S|^2
    v: _Vec                    # the shoulder point seen from link 6 (basis w5, w6, w5 x w6)


class _Elbow(NamedTuple):
    """Step 2 and the A4-dependent vectors of step 3 for one elbow choice."""

    q4: np.ndarray
    k: np.ndarray              # cos(q4 - g4)
    sphi: np.ndarray           # |sin(q4 - g4)|
    u: _Vec
    g_vec: _Vec                # R_F6^T Rot(w4, -q4) w3
    h_vec: _Vec                # R_F6^T Rot(w4, -q4) y
    ok: np.ndarray


class PandaArm:
    """A Panda-type arm from :class:`~fabric.robot.panda_derive.PandaParams` (the ``ClosedFormArm`` interface)."""

    family = "panda"
    nq = 7
    free_joint = 6             # A7: the redundancy parameter, an input of every IK call

    def __init__(self, params: PandaParams) -> None:
        self.params = params
        w = np.asarray(params.directions, dtype=float)
        P = np.asarray(params.points_mm, dtype=float)
        self.beta = float(params.offset2_rad)
        self.flange_T = np.asarray(params.flange_T, dtype=float)
        B = np.asarray(params.base_T, dtype=float)
        self._base: np.ndarray | None = None if np.array_equal(B, np.eye(4)) else B
        E0 = np.asarray(params.end_T, dtype=float)
        w4, P4, W0 = w[3], P[3], P[4]
        RF = np.column_stack([w[4], w[5], np.cross(w[4], w[5])])            # link-6 basis (w5, w6, w5 x w6)
        self._RF, self._w4 = RF, w4
        self._K = E0[:3, :3].T @ RF                                         # R6 = [x' y' z] K
        self._kW = E0[:3, :3].T @ (W0 - E0[:3, 3])                          # W = p + [x' y' z] kW
        # the triangle: |W - S|^2 = D - 2 (A cos q4 + B sin q4) = D - 2 R4 cos(q4 - g4)
        s, wv = -P4, W0 - P4
        cst = float((s @ w4) * (wv @ w4))
        A, Bs = float(s @ wv) - cst, float(s @ np.cross(w4, wv))
        self._D = float(s @ s + wv @ wv) - 2.0 * cst
        R4 = float(np.hypot(A, Bs))
        self._inv2R4 = 0.5 / R4
        self._cg, self._sg, self._g4 = A / R4, Bs / R4, float(np.arctan2(Bs, A))
        # vectors turned back by A4, in the link-6 basis: x(q4) = X0 + cos q4 X1 + sin q4 X2
        self._u = self._turned(s, RF.T @ (P4 - W0))
        self._gv = self._turned(w[2])
        self._hv = self._turned(np.array([0.0, 1.0, 0.0]))
        self._w, self._P, self._E0 = w, P, E0

    def _turned(self, x: np.ndarray, shift: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
        """``R_F6^T Rot(w4, -q4) x (+ shift)`` as constants ``(X0, X1, X2, Xk, Xs)``: ``X0 + cos q4 X1 + sin q4 X2``,
        or with ``q4 = g4 + e phi``: ``X0 + cos(phi) Xk + e sin(phi) Xs``."""
        w4, RF = self._w4, self._RF
        along = float(w4 @ x)
        X0 = RF.T @ (along * w4) + (0.0 if shift is None else shift)
        X1 = RF.T @ (x - along * w4)
        X2 = -(RF.T @ np.cross(w4, x))
        return X0, X1, X2, self._cg * X1 + self._sg * X2, -self._sg * X1 + self._cg * X2

    # Forward kinematics ----------------------------------------------------
    def fk_flange(self, q_rad: np.ndarray) -> np.ndarray:
        """URDF flange poses (N, 4, 4) mm for joints (N, 7); (4, 4) for (7,)."""
        q = np.asarray(q_rad, dtype=float)
        single = q.ndim == 1
        q = np.atleast_2d(q)
        n = len(q)
        R: list[list[_Num]] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        t: list[_Num] = [0.0, 0.0, 0.0]
        for j in range(7):                    # G <- G exp(xi_j q_j): R <- R Rj, t <- t + R (p_j - Rj p_j)
            Rj = _axis_rotation(self._w[j], q[:, j])
            pj: list[_Num] = list(self._P[j].tolist())
            d = [pj[a] - _row_dot(Rj[a], pj) for a in range(3)]
            t = [t[a] + _row_dot(R[a], d) for a in range(3)]
            R = _matmul(R, Rj)
        # the flange: Base @ G @ E0 @ flange_T (Base, E0 and flange_T constant)
        Rout = _matmul(R, _rows(self._E0[:3, :3]))
        pE: list[_Num] = [float(v) for v in self._E0[:3, 3]]
        pout = [t[a] + _row_dot(R[a], pE) for a in range(3)]
        if self._base is not None:
            BR = _rows(self._base[:3, :3])
            Rout = _matmul(BR, Rout)
            pout = [float(self._base[a, 3]) + _row_dot(BR[a], pout) for a in range(3)]
        out = np.zeros((n, 4, 4))
        for a in range(3):
            for b in range(3):
                out[:, a, b] = Rout[a][b]
            out[:, a, 3] = pout[a]
        out[:, 3, 3] = 1.0
        if not np.array_equal(self.flange_T, np.eye(4)):
            out = out @ self.flange_T
        return out[0] if single else out

    # Inverse kinematics ----------------------------------------------------
    def native_constants(self) -> list[float]:
        """armik.c's ``F_*`` constants of the Panda type: K (row by row), kW, the turned vectors u, g, h (each
        part), D, 1 / (2 R4), g4 and beta."""
        turned = [float(v) for X in (self._u, self._gv, self._hv) for part in X for v in part]
        return [*np.asarray(self._K, dtype=float).ravel().tolist(), *np.asarray(self._kW, dtype=float).tolist(),
                *turned, float(self._D), float(self._inv2R4), float(self._g4), float(self.beta)]

    def model_cols(self, C: np.ndarray) -> np.ndarray:
        """End-frame columns in the model base (origin at the shoulder)."""
        return cols_in_frame(self._base, C)

    def _link6(self, C: np.ndarray, q7: _Num) -> _Link6:
        """Step 1 of the module docstring."""
        p: _Vec = (C[0], C[1], C[2])
        z: _Vec = (C[3], C[4], C[5])
        y: _Vec = (C[6], C[7], C[8])
        x: _Vec = (y[1] * z[2] - y[2] * z[1], y[2] * z[0] - y[0] * z[2], y[0] * z[1] - y[1] * z[0])
        c7, s7 = np.cos(q7), np.sin(q7)
        xr: _Vec = (c7 * x[0] - s7 * y[0], c7 * x[1] - s7 * y[1], c7 * x[2] - s7 * y[2])
        yr: _Vec = (s7 * x[0] + c7 * y[0], s7 * x[1] + c7 * y[1], s7 * x[2] + c7 * y[2])
        cols = (xr, yr, z)
        R6 = (_lin(cols, self._K[:, 0]), _lin(cols, self._K[:, 1]), _lin(cols, self._K[:, 2]))
        off = _lin(cols, self._kW)
        W: _Vec = (p[0] + off[0], p[1] + off[1], p[2] + off[2])
        WW = _dot(W, W)
        v: _Vec = (-_dot(R6[0], W), -_dot(R6[1], W), -_dot(R6[2], W))
        return _Link6(R6, W, WW, v)

    def _elbow(self, l6: _Link6, elbow: int) -> _Elbow:
        """Step 2 and the vectors of step 3 that depend on A4, for one elbow choice."""
        k = (self._D - l6.WW) * self._inv2R4
        ok = np.abs(k) <= 1.0 + 1e-12
        k = np.clip(k, -1.0, 1.0)
        sphi = np.sqrt(1.0 - k * k)
        esp = -sphi if elbow else sphi
        q4 = wrap(self._g4 + np.arctan2(esp, k))

        def at(X: tuple[np.ndarray, ...]) -> _Vec:
            X0, Xk, Xs = X[0], X[3], X[4]
            return (X0[0] + k * Xk[0] + esp * Xs[0], X0[1] + k * Xk[1] + esp * Xs[1], X0[2] + k * Xk[2] + esp * Xs[2])

        return _Elbow(q4, k, sphi, at(self._u), at(self._gv), at(self._hv), ok)

    @staticmethod
    def _upper_arm(l6: _Link6, g_vec: _Vec, h_vec: _Vec, c5: np.ndarray, s5: np.ndarray, c6: np.ndarray,
                   s6: np.ndarray) -> tuple[_Vec, _Vec]:
        """``d = R3 w3`` and ``m = R3 y`` for given wrist angles: ``R6 RotY(-q6) RotX(-q5)`` of the turned vectors."""
        R0, R1, R2 = l6.R6
        out = []
        for a, b, c in (g_vec, h_vec):
            b1, c1 = c5 * b + s5 * c, c5 * c - s5 * b             # RotX(-q5)
            a2, c2 = c6 * a - s6 * c1, s6 * a + c6 * c1            # RotY(-q6)
            out.append((R0[0] * a2 + R1[0] * b1 + R2[0] * c2, R0[1] * a2 + R1[1] * b1 + R2[1] * c2,
                        R0[2] * a2 + R1[2] * b1 + R2[2] * c2))
        return out[0], out[1]

    def _shoulder(self, d: _Vec, m: _Vec, sign: _Num, q1_hold: np.ndarray | None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Step 4: q1, q2, q3 and ``|sin(q2 + beta)|`` for a shoulder ``sign`` (+1: A1 turned towards the upper
        arm, -1: away from it, reaching over the top).

        Rows whose upper arm is on axis 1 (``|sin| < FREE_SIN``) take A1 from ``q1_hold`` when given
        (already turned for the shoulder); q2 and q3 then follow exactly from it.
        """
        dx, dy, dz = d
        h = np.hypot(dx, dy)
        inv = 1.0 / np.where(h > 0.0, h, 1.0)
        c1 = np.where(h > 0.0, sign * dx * inv, sign * 1.0)
        s1 = sign * dy * inv
        q1 = np.arctan2(s1, c1)
        if q1_hold is not None:
            free = h < FREE_SIN
            if free.any():
                hold = np.asarray(q1_hold, dtype=float)
                q1 = np.where(free, hold, q1)
                c1, s1 = np.where(free, np.cos(hold), c1), np.where(free, np.sin(hold), s1)
        cx = c1 * dx + s1 * dy                                   # sin(q2 + beta) (= sign * h)
        q2 = np.arctan2(cx, dz)
        if self.beta:
            q2 = wrap(q2 - self.beta)
        mx, my, mz = m
        mx1, my1 = c1 * mx + s1 * my, c1 * my - s1 * mx          # RotZ(-q1) m
        q3 = np.arctan2(cx * mz - dz * mx1, my1)                 # RotY(-q2 - beta) of that is (-s3, c3, 0)
        return q1, q2, q3, h

    @staticmethod
    def _wrist_reach(l6: _Link6, el: _Elbow) -> tuple[np.ndarray, np.ndarray]:
        """Step 3's ``g`` (the intermediate vector's third component, >= 0) and the rows the wrist reaches."""
        ua, ub, uc = el.u
        va, vb, vc = l6.v
        g2 = 0.5 * ((ub * ub + uc * uc - vb * vb) + (va * va + vc * vc - ua * ua))
        return np.sqrt(np.maximum(g2, 0.0)), g2 >= -1e-12 * l6.WW

    @staticmethod
    def _wrist(l6: _Link6, el: _Elbow, g: np.ndarray, wrist: int) -> tuple[np.ndarray, ...]:
        """Step 3 for one wrist choice: ``q5, q6`` and their cosines and sines ``c5, s5, c6, s6``."""
        ua, ub, uc = el.u
        va, vb, vc = l6.v
        gw = -g if wrist else g
        y5, x5 = uc * vb - ub * gw, ub * vb + uc * gw
        y6, x6 = vc * ua - va * gw, vc * gw + va * ua
        h5, h6 = np.hypot(x5, y5), np.hypot(x6, y6)
        i5, i6 = 1.0 / np.where(h5 > 0.0, h5, 1.0), 1.0 / np.where(h6 > 0.0, h6, 1.0)
        c5, s5 = np.where(h5 > 0.0, x5 * i5, 1.0), y5 * i5
        c6, s6 = np.where(h6 > 0.0, x6 * i6, 1.0), y6 * i6
        return np.arctan2(y5, x5), np.arctan2(y6, x6), c5, s5, c6, s6

    def _branches(self, C: np.ndarray, shoulders: tuple[int, ...], wrists: tuple[int, ...],
                  elbows: tuple[int, ...], q1_hold: np.ndarray | None, q7: _Num
                  ) -> dict[int, tuple[np.ndarray, ...]]:
        """Joints (7, N), reach, singular and gap of the branches chosen, sharing the work of common steps.

        The second shoulder of a pair is the first turned over the top, ``(q1 + pi, -(q2 + beta) - beta,
        q3 + pi)``, the same ``R3`` (unless A1 is held).
        """
        n = C.shape[1]
        l6 = self._link6(C, q7)
        q7_row = np.full(n, wrap(np.asarray(q7, dtype=float))) if np.ndim(q7) == 0 else wrap(np.asarray(q7))
        norm_w = np.sqrt(l6.WW)
        out: dict[int, tuple[np.ndarray, ...]] = {}
        for e in elbows:
            el = self._elbow(l6, e)
            g, ok_w = self._wrist_reach(l6, el)
            ok = el.ok & ok_w
            gap_w = np.maximum(np.arctan2(g, np.abs(el.u[0])), np.arctan2(g, np.abs(l6.v[1])))
            gap = np.minimum(np.minimum(2.0 * np.arctan2(el.sphi, np.abs(el.k)), 2.0 * gap_w), np.pi)
            sing_ew = ok & ((el.sphi < ELBOW_SING_COS) | (g < WRIST_SING_SIN * norm_w))   # of the reached ones
            for w in wrists:
                q5, q6, c5, s5, c6, s6 = self._wrist(l6, el, g, w)
                d, m = self._upper_arm(l6, el.g_vec, el.h_vec, c5, s5, c6, s6)
                first: tuple[np.ndarray, ...] | None = None
                for s in shoulders:
                    if first is not None and q1_hold is None:         # over the top of the first shoulder
                        q1, q2, q3, h = flip(first[0]), wrap(-first[1] - 2.0 * self.beta), flip(first[2]), first[3]
                    else:
                        hold = None if q1_hold is None else (flip(wrap(q1_hold)) if s else q1_hold)
                        q1, q2, q3, h = self._shoulder(d, m, -1.0 if s else 1.0, hold)
                        first = (q1, q2, q3, h)
                    q = np.stack([q1, q2, q3, el.q4, q5, q6, q7_row])
                    out[4 * s + 2 * e + w] = (q, ok, sing_ew | (ok & (h < WRIST_SING_SIN)), gap)
        return out

    def q1_free(self, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """No rows: A1 is undefined only where the upper arm lies on axis 1, which depends on the branch.

        Those rows are the shoulder's gimbal lock, caught on the chosen joints by :meth:`wrist_degenerate` and
        held by :meth:`resolve_wrist` like a spherical wrist at q5 = 0; no pre-pass over the targets is needed.
        """
        n = C.shape[1]
        return np.zeros(n), np.zeros(n, dtype=bool)

    def ik_branches_cols(self, C: np.ndarray, q1_hold: np.ndarray | None = None, q_free: _Num | None = None
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All 8 branches of end-frame columns ``C`` (9, N) for A7 = ``q_free`` ((N,) or a number; default 0):
        ``q (N, 8, 7), reach (N, 8), singular (N, 8)``."""
        res = self._branches(self.model_cols(C), (0, 1), (0, 1), (0, 1), q1_hold, 0.0 if q_free is None else q_free)
        return stack_branches(res, 7, C.shape[1])

    def ik_branch_cols(self, C: np.ndarray, branch: int, q1_hold: np.ndarray | None = None,
                       q_free: _Num | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One branch for every row: ``q (7, N), reach, singular, gap_rad`` (see ``arm_family``)."""
        res = self._branches(self.model_cols(C), (branch // 4,), (branch % 2,), ((branch // 2) % 2,), q1_hold,
                             0.0 if q_free is None else q_free)
        q, ok, sing, gap = res[branch]
        return q, ok, sing, gap

    # Singularities ---------------------------------------------------------
    def _wrist_terms(self, q: np.ndarray) -> tuple[np.ndarray, ...]:
        """From joints (7, N): ``u`` (the shoulder point from link 4, A4 undone), ``|u|`` and the intermediate
        vector's components ``c_b``, ``c_c`` (``RotX(-q5) u``)."""
        X0, X1, X2 = self._u[:3]
        c4, s4 = np.cos(q[3]), np.sin(q[3])
        ua, ub, uc = (X0[i] + c4 * X1[i] + s4 * X2[i] for i in range(3))
        c5, s5 = np.cos(q[4]), np.sin(q[4])
        return ua, ub, uc, np.sqrt(ua * ua + ub * ub + uc * uc), c5 * ub + s5 * uc, c5 * uc - s5 * ub

    def wrist_sin(self, q: np.ndarray) -> np.ndarray:
        """Distance from the singularities of joints (7, N) as a sine, 0 there: the smaller of the shoulder's
        ``|sin(q2 + beta)|`` (axes 1 and 3 aligned) and ``g / |W - S|`` (the two wrist solutions meeting)."""
        _, _, _, norm, _, cc = self._wrist_terms(q)
        return np.minimum(np.abs(np.sin(q[1] + self.beta)), np.abs(cc) / np.maximum(norm, 1e-300))

    def wrist_degenerate(self, q: np.ndarray) -> np.ndarray:
        """Rows of joints (7, N) where one angle is free: axes 1 and 3 aligned (A1), or the shoulder point on
        axis 5 (A5) or on axis 6 (A6)."""
        _, ub, uc, norm, cb, _ = self._wrist_terms(q)
        tiny = FREE_SIN * norm
        on5 = np.hypot(ub, uc) < tiny
        on6 = np.sqrt(np.maximum(norm * norm - cb * cb, 0.0)) < tiny
        return (np.abs(np.sin(q[1] + self.beta)) < FREE_SIN) | on5 | on6

    def resolve_wrist(self, C: np.ndarray, q: np.ndarray, held: np.ndarray) -> np.ndarray:
        """Joints (7, M) of degenerate rows with the free angle (A1, A5 or A6) from ``held`` (7, M), still exact.

        The elbow (A4), A7 and the side of the shoulder (the sign of ``sin(q2 + beta)``) are kept from ``q``.
        """
        l6 = self._link6(self.model_cols(C), q[6])
        (ua, ub, uc), g_vec, h_vec = (self._at_q4(X, q[3]) for X in (self._u, self._gv, self._hv))
        va, vb, vc = l6.v
        tiny = FREE_SIN * np.sqrt(l6.WW)
        on5 = np.hypot(ub, uc) < tiny                           # the shoulder point on axis 5: A5 free
        on6 = ~on5 & (np.hypot(va, vc) < tiny)                  # ... on axis 6: A6 free
        q5, q6 = np.where(on5, held[4], q[4]), np.where(on6, held[5], q[5])
        if on5.any():                                           # A5 held: turn u by it, then A6 as in step 3
            c5, s5 = np.cos(q5), np.sin(q5)
            cc = c5 * uc - s5 * ub                              # (RotX(-q5) u)_c
            q6 = np.where(on5, np.arctan2(vc * ua - va * cc, vc * cc + va * ua), q6)
        if on6.any():                                           # A6 held: turn v by it, then A5
            c6, s6 = np.cos(q6), np.sin(q6)
            rb, rc = vb, c6 * vc - s6 * va
            q5 = np.where(on6, -np.arctan2(ub * rc - uc * rb, ub * rb + uc * rc), q5)
        d, m = self._upper_arm(l6, g_vec, h_vec, np.cos(q5), np.sin(q5), np.cos(q6), np.sin(q6))
        sign = np.where(np.sin(q[1] + self.beta) < 0.0, -1.0, 1.0)
        q1, q2, q3, _ = self._shoulder(d, m, sign, held[0])    # A1 held where the upper arm is on axis 1
        out = q.copy()
        out[0], out[1], out[2], out[4], out[5] = q1, q2, q3, q5, q6
        return out

    def _at_q4(self, X: tuple[np.ndarray, ...], q4: np.ndarray) -> _Vec:
        """A turned vector (``_turned``) at joint values ``q4`` (M,)."""
        c4, s4 = np.cos(q4), np.sin(q4)
        X0, X1, X2 = X[:3]
        return (X0[0] + c4 * X1[0] + s4 * X2[0], X0[1] + c4 * X1[1] + s4 * X2[1], X0[2] + c4 * X1[2] + s4 * X2[2])


def _axis_rotation(w: np.ndarray, q: np.ndarray) -> list[list[_Num]]:
    """``Rot(w, q) = I + s K + (1 - c) K^2`` entry by entry, constant 0 / 1 entries kept as numbers."""
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    K2 = K @ K
    s, vc = np.sin(q), 1.0 - np.cos(q)
    out: list[list[_Num]] = []
    for a in range(3):
        row: list[_Num] = []
        for b in range(3):
            k, k2 = float(K[a, b]), float(K2[a, b])
            entry: _Num = 1.0 if a == b else 0.0
            if k != 0.0:
                entry = entry + (s if k == 1.0 else (-s if k == -1.0 else k * s))
            if abs(k2) > 1e-15:
                entry = entry + (vc if k2 == 1.0 else (-vc if k2 == -1.0 else k2 * vc))
            row.append(entry)
        out.append(row)
    return out


def _mul(a: _Num, b: _Num) -> _Num | None:
    """``a * b`` with constant 0 and 1 short-cut (None for a zero product)."""
    if isinstance(a, float):
        if a == 0.0:
            return None
        if a == 1.0:
            return b
        if a == -1.0:
            return -b
    if isinstance(b, float):
        if b == 0.0:
            return None
        if b == 1.0:
            return a
        if b == -1.0:
            return -a
    return a * b


def _rows(M: np.ndarray) -> list[list[_Num]]:
    """A constant matrix as nested lists of numbers (for :func:`_matmul`)."""
    return [[float(v) for v in r] for r in M]


def _row_dot(row: list[_Num], vec: list[_Num]) -> _Num:
    acc: _Num = 0.0
    for a, b in zip(row, vec, strict=True):
        term = _mul(a, b)
        if term is not None:
            acc = term if isinstance(acc, float) and acc == 0.0 else acc + term
    return acc


def _matmul(A: list[list[_Num]], B: list[list[_Num]]) -> list[list[_Num]]:
    out: list[list[_Num]] = []
    for a in range(3):
        row: list[_Num] = []
        for c in range(3):
            acc: _Num = 0.0
            for b in range(3):
                term = _mul(A[a][b], B[b][c])
                if term is not None:
                    acc = term if isinstance(acc, float) and acc == 0.0 else acc + term
            row.append(acc)
        out.append(row)
    return out
