"""Closed-form, vectorised kinematics of UR-type arms (three parallel axes, offset wrist), all 8 branches.

The model and its parameters are those of ``ur_derive.py`` (standard UR DH
table); the frames are those of :func:`~fabric.robot.ur_derive.ur_dh_frames`.

Inverse kinematics, per target (DH frame 6: origin ``p``, axes ``x6, y6, z6``
in the DH base):

1. Axis 6 ends ``d6`` beyond the axis-5 point ``p5 = p - d6 z6``, which lies
   ``d4`` off the arm plane: ``p5 . z1 = d4`` with ``z1 = (s1, -c1, 0)``. With
   ``r^2 = p5x^2 + p5y^2`` and ``t = sqrt(r^2 - d4^2)`` (shoulder: ``+-t``, the
   radial distance of p5 in the arm plane), ``(c1, s1) = (+-t p5x - d4 p5y,
   +-t p5y + d4 p5x) / r^2``: no trigonometric call.
2. ``z1`` seen from the flange gives A5 and A6: ``z1 . z6 = c5``, ``z1 . x6 =
   s5 c6``, ``z1 . y6 = -s5 s6``, so ``|s5| = |(z1 . x6, z1 . y6)|`` and the
   wrist choice is the sign of s5 (equivalently, the flange's offset from the
   plane, ``p . z1 = d4 + d6 c5``, once A1 is set).
3. Frame 4 follows: ``x4 = c5 c6 x6 - c5 s6 y6 - s5 z6`` and ``z4 = -s6 x6 -
   c6 y6``, so ``theta234 = atan2(x4 . y1, x4 . x1)`` and axis 4 passes through
   ``p5 - d5 z4``, at ``(X, Y)`` in the arm plane: a planar 2R problem
   (``cos theta3 = (X^2 + Y^2 - a2^2 - a3^2) / (2 a2 a3)``, elbow: +-), then
   ``theta4 = theta234 - theta2 - theta3``.

Singular rows (flagged; the exact solution is still returned): ``|s5| <
WRIST_SING_SIN`` (axes 4 and 6 parallel: A6 is then only defined together with
A2..A4, and where s5 is exactly 0 the solver holds A6 and re-solves A2..A4),
``|sin theta3| < ELBOW_SING_COS`` (arm stretched or folded) and ``t <
SHOULDER_SING_MM`` (the axis-5 point on the cylinder of radius d4 about axis
1: both shoulders meet). Branches differ by pi in A6 (wrist), by ``2|theta3|``
in A3 (elbow) and by ``2 atan2(t, |d4|)`` in A1 (shoulder): the ``gap`` the
solver's continuity test needs.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fabric.robot.arm_family import cols_in_frame, stack_branches
from fabric.robot.kinematics import ELBOW_SING_COS, SHOULDER_SING_MM, WRIST_SING_SIN, flip, wrap
from fabric.robot.ur_derive import URParams, ur_dh_frames

__all__ = ["URArm"]


class _Shoulder(NamedTuple):
    """A1 of one shoulder choice, with its cosine and sine, and the rows it reaches."""

    th1: np.ndarray
    c1: np.ndarray
    s1: np.ndarray
    ok: np.ndarray
    t: np.ndarray


class _Plane(NamedTuple):
    """Step 3 before the elbow choice: theta234, the axis-4 point (X, Y) in the arm plane, cos / |sin| theta3."""

    th234: np.ndarray
    X: np.ndarray
    Y: np.ndarray
    c3: np.ndarray
    sabs: np.ndarray
    ok: np.ndarray


class URArm:
    """A UR-type arm from :class:`~fabric.robot.ur_derive.URParams` (the ``ClosedFormArm`` interface)."""

    family = "ur"
    nq = 6
    free_joint = None          # 6 axes: no redundancy parameter (``q_free`` is ignored)

    def __init__(self, params: URParams) -> None:
        self.params = params
        self.d1, self.a2, self.a3 = params.d1_mm, params.a2_mm, params.a3_mm
        self.d4, self.d5, self.d6 = params.d4_mm, params.d5_mm, params.d6_mm
        self.off = np.asarray(params.offsets_rad, dtype=float)
        self.sign = np.asarray(params.signs, dtype=float)
        self.flange_T = np.asarray(params.flange_T, dtype=float)
        B = np.asarray(params.base_T, dtype=float)
        self._base: np.ndarray | None = None if np.allclose(B, np.eye(4), atol=1e-15, rtol=0) else B

    # Joint <-> model angles ------------------------------------------------
    def _theta(self, q: np.ndarray, j: int) -> np.ndarray:
        s, o = self.sign[j], self.off[j]
        return ((q if s > 0 else -q) + o) if o else (q if s > 0 else -q)

    def _q(self, theta: np.ndarray, j: int) -> np.ndarray:
        s, o = self.sign[j], self.off[j]
        if o:
            return wrap(theta - o if s > 0 else o - theta)
        return theta if s > 0 else -theta

    # Forward kinematics ----------------------------------------------------
    def fk_flange(self, q_rad: np.ndarray) -> np.ndarray:
        """URDF flange poses (N, 4, 4) mm for joints (N, 6); (4, 4) for (6,)."""
        q = np.asarray(q_rad, dtype=float)
        single = q.ndim == 1
        q = np.atleast_2d(q)
        th = [self._theta(q[:, j], j) for j in range(6)]
        x6, y6, z6, p = ur_dh_frames(th, self.d1, self.a2, self.a3, self.d4, self.d5, self.d6)
        T = np.zeros((len(q), 4, 4))
        T[:, :3, 0], T[:, :3, 1], T[:, :3, 2], T[:, :3, 3] = x6, y6, z6, p
        T[:, 3, 3] = 1.0
        if self._base is not None:
            T = self._base @ T
        T = T @ self.flange_T
        return T[0] if single else T

    # Inverse kinematics ----------------------------------------------------
    def native_constants(self) -> list[float]:
        """armik.c's ``ur_branch`` constants: d1, a2, a3, d4, d5, d6."""
        return [float(v) for v in (self.d1, self.a2, self.a3, self.d4, self.d5, self.d6)]

    def model_cols(self, C: np.ndarray) -> np.ndarray:
        """DH frame-6 columns in the DH base (the URDF base unless axis 1 is placed otherwise)."""
        return cols_in_frame(self._base, C)

    def _shoulder(self, C: np.ndarray, shoulder: int, q1_hold: np.ndarray | None) -> _Shoulder:
        """Step 1 of the module docstring."""
        p5x, p5y = C[0] - self.d6 * C[3], C[1] - self.d6 * C[4]
        r2 = p5x * p5x + p5y * p5y
        t = np.sqrt(np.maximum(r2 - self.d4 * self.d4, 0.0))
        ok = r2 >= self.d4 * self.d4
        if q1_hold is not None:
            th1 = wrap(self._theta(np.asarray(q1_hold, dtype=float), 0))
            th1 = flip(th1) if shoulder else th1
            return _Shoulder(th1, np.cos(th1), np.sin(th1), ok, t)
        ts = -t if shoulder else t
        inv = 1.0 / np.where(r2 > 0.0, r2, 1.0)
        c1 = (ts * p5x - self.d4 * p5y) * inv
        s1 = (ts * p5y + self.d4 * p5x) * inv
        return _Shoulder(np.arctan2(s1, c1), c1, s1, ok, t)

    def q1_free(self, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A1 of the first shoulder; undefined only with the axis-5 point on axis 1 (d4 = 0)."""
        Cm = self.model_cols(C)
        sh = self._shoulder(Cm, 0, None)
        p5x, p5y = Cm[0] - self.d6 * Cm[3], Cm[1] - self.d6 * Cm[4]
        return self._q(sh.th1, 0), p5x * p5x + p5y * p5y < 1e-12

    def _wrist(self, C: np.ndarray, X6: tuple[np.ndarray, ...], sh: _Shoulder, wrist: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Step 2: ``c5, s5, c6, s6, |s5|`` (``X6``: the x column of the target).

        ``c5 = z1 . z6`` and ``|s5| = |(z1 . x6, z1 . y6)|`` read the wrist from
        the orientation alone (equal to the position form ``(p . z1 - d4) / d6``
        once A1 puts p5 at ``d4`` off the plane), so a small s5 keeps full
        precision instead of the square root of a rounding error.
        """
        c1, s1 = sh.c1, sh.s1
        c5 = s1 * C[3] - c1 * C[4]
        zx6 = s1 * X6[0] - c1 * X6[1]
        zy6 = s1 * C[6] - c1 * C[7]
        h = np.hypot(zx6, zy6)
        inv = 1.0 / np.where(h > 0.0, h, 1.0)
        sgn = -1.0 if wrist else 1.0
        c6 = np.where(h > 0.0, sgn * zx6 * inv, 1.0)
        s6 = -sgn * zy6 * inv
        return c5, sgn * h, c6, s6, h

    def _plane(self, C: np.ndarray, X6: tuple[np.ndarray, ...], sh: _Shoulder, c5: np.ndarray, s5: np.ndarray,
               c6: np.ndarray, s6: np.ndarray) -> _Plane:
        """Step 3 up to the elbow choice: theta234 and the axis-4 point in the arm plane."""
        px, py, pz = C[0], C[1], C[2]
        zx, zy, zz, yx, yy, yz = C[3], C[4], C[5], C[6], C[7], C[8]
        xx, xy, xz = X6
        c1, s1 = sh.c1, sh.s1
        a, b, cc = c5 * c6, -c5 * s6, -s5
        x4x, x4y, x4z = a * xx + b * yx + cc * zx, a * xy + b * yy + cc * zy, a * xz + b * yz + cc * zz
        th234 = np.arctan2(x4z, c1 * x4x + s1 * x4y)
        d5, d6 = self.d5, self.d6
        ox = px - d6 * zx + d5 * (s6 * xx + c6 * yx)          # p5 - d5 z4, z4 = -s6 x6 - c6 y6
        oy = py - d6 * zy + d5 * (s6 * xy + c6 * yy)
        oz = pz - d6 * zz + d5 * (s6 * xz + c6 * yz)
        X, Y = c1 * ox + s1 * oy, oz - self.d1
        a2, a3 = self.a2, self.a3
        c3 = (X * X + Y * Y - a2 * a2 - a3 * a3) / (2.0 * a2 * a3)
        ok = np.abs(c3) <= 1.0 + 1e-12
        c3 = np.clip(c3, -1.0, 1.0)
        return _Plane(th234, X, Y, c3, np.sqrt(1.0 - c3 * c3), ok)

    def _elbow(self, pl: _Plane, elbow: int | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """theta2, theta3, theta4 of one elbow choice (1, or True per row, takes sin theta3 < 0)."""
        s3 = np.where(elbow, -pl.sabs, pl.sabs) if isinstance(elbow, np.ndarray) else (-pl.sabs if elbow else pl.sabs)
        A, Bk = self.a2 + self.a3 * pl.c3, self.a3 * s3
        th2 = np.arctan2(pl.Y * A - pl.X * Bk, pl.X * A + pl.Y * Bk)
        th3 = np.arctan2(s3, pl.c3)
        return th2, th3, wrap(pl.th234 - th2 - th3)

    def _branches(self, C: np.ndarray, shoulders: tuple[int, ...], wrists: tuple[int, ...],
                  elbows: tuple[int, ...], q1_hold: np.ndarray | None) -> dict[int, tuple[np.ndarray, ...]]:
        """Joints (6, N), reach, singular and gap of the branches chosen, sharing the work of common steps."""
        X6 = (C[7] * C[5] - C[8] * C[4], C[8] * C[3] - C[6] * C[5], C[6] * C[4] - C[7] * C[3])
        out: dict[int, tuple[np.ndarray, ...]] = {}
        for sh_i in shoulders:
            sh = self._shoulder(C, sh_i, q1_hold)
            q1 = self._q(sh.th1, 0)
            sh_gap = 2.0 * np.arctan2(sh.t, abs(self.d4))
            for w in wrists:
                c5, s5, c6, s6, h = self._wrist(C, X6, sh, w)
                q5, q6 = self._q(np.arctan2(s5, c5), 4), self._q(np.arctan2(s6, c6), 5)
                pl = self._plane(C, X6, sh, c5, s5, c6, s6)
                ok = sh.ok & pl.ok
                sing = (h < WRIST_SING_SIN) | (pl.sabs < ELBOW_SING_COS) | (sh.t < SHOULDER_SING_MM)
                gap = np.minimum(2.0 * np.arctan2(pl.sabs, np.abs(pl.c3)), sh_gap)
                for e in elbows:
                    th2, th3, th4 = self._elbow(pl, e)
                    q = np.stack([q1, self._q(th2, 1), self._q(th3, 2), self._q(th4, 3), q5, q6])
                    out[4 * sh_i + 2 * e + w] = (q, ok, sing, gap)
        return out

    def ik_branches_cols(self, C: np.ndarray, q1_hold: np.ndarray | None = None,
                         q_free: float | np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All 8 branches of DH frame-6 columns ``C`` (9, N): ``q (N, 8, 6), reach (N, 8), singular (N, 8)``."""
        res = self._branches(self.model_cols(C), (0, 1), (0, 1), (0, 1), q1_hold)
        return stack_branches(res, 6, C.shape[1])

    def ik_branch_cols(self, C: np.ndarray, branch: int, q1_hold: np.ndarray | None = None,
                       q_free: float | np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One branch for every row: ``q (6, N), reach, singular, gap_rad`` (see ``arm_family``)."""
        res = self._branches(self.model_cols(C), (branch // 4,), (branch % 2,), ((branch // 2) % 2,), q1_hold)
        q, ok, sing, gap = res[branch]
        return q, ok, sing, gap

    # Wrist singularity -----------------------------------------------------
    def wrist_sin(self, q: np.ndarray) -> np.ndarray:
        """``|sin theta5|`` of joints (6, N): 0 at the wrist singularity (axes 4 and 6 parallel)."""
        return np.abs(np.sin(self._theta(q[4], 4)))

    def wrist_degenerate(self, q: np.ndarray) -> np.ndarray:
        """Rows of joints (6, N) with sin(theta5) = 0: axes 4 and 6 parallel, A6 free."""
        return np.abs(np.sin(self._theta(q[4], 4))) < 1e-9

    def resolve_wrist(self, C: np.ndarray, q: np.ndarray, held: np.ndarray) -> np.ndarray:
        """Hold A6 at ``held[5]`` and re-solve A2..A4 (same elbow) exactly on wrist-degenerate rows (6, M)."""
        Cm = self.model_cols(C)
        th1, th3, th5 = self._theta(q[0], 0), self._theta(q[2], 2), self._theta(q[4], 4)
        th6 = self._theta(held[5], 5)
        r2 = (Cm[0] - self.d6 * Cm[3]) ** 2 + (Cm[1] - self.d6 * Cm[4]) ** 2
        sh = _Shoulder(th1, np.cos(th1), np.sin(th1), np.ones(len(th1), dtype=bool),
                       np.sqrt(np.maximum(r2 - self.d4 ** 2, 0.0)))
        X6 = (Cm[7] * Cm[5] - Cm[8] * Cm[4], Cm[8] * Cm[3] - Cm[6] * Cm[5], Cm[6] * Cm[4] - Cm[7] * Cm[3])
        pl = self._plane(Cm, X6, sh, np.cos(th5), np.sin(th5), np.cos(th6), np.sin(th6))
        th2, th3n, th4 = self._elbow(pl, np.sin(th3) < 0.0)
        out = q.copy()
        out[1], out[2], out[3], out[5] = self._q(th2, 1), self._q(th3n, 2), self._q(th4, 3), held[5]
        return out
