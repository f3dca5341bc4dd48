"""Closed-form, vectorised kinematics of OPW arms (parallel base axes, spherical wrist: ABB, KUKA, Fanuc, Staubli).

The model and its parameters are those of ``opw_derive.py``; here are the
forward kinematics and the 8 IK branches over N targets at once.

Inverse kinematics, per target (columns of the end frame in the OPW base):
the wrist centre ``c = p - c4 * z`` fixes A1 up to the shoulder choice. With
``rho^2 = cx^2 + cy^2`` and ``t = sqrt(rho^2 - b^2)`` (the wrist centre's
distance from axis 1 within the arm plane), ``theta1 = atan2(cy, cx) -
atan2(b, t)`` (front) or ``atan2(cy, cx) + atan2(b, t) - pi`` (back; over the
top), and the wrist centre sits at ``u = +-t - a1`` forward of axis 2 and
``v = cz - c1`` above it. The upper arm (``c2``) and the forearm (length
``k = hypot(a2, c3)``, angle ``phi = atan2(a2, c3)`` off its axis) form a
triangle: ``cos(psi) = (u^2 + v^2 - c2^2 - k^2) / (2 c2 k)`` with ``psi =
theta3 + phi`` (elbow: +-), and ``theta2 = atan2(u, v) - atan2(k sin psi, c2 +
k cos psi)``. The wrist is ZYZ Euler angles of ``Rc = Ry(theta2 + theta3)^T
Rz(theta1)^T R``: ``theta4 = atan2(Rc12, Rc02)``, ``theta5 = atan2(h, Rc22)``
with ``h = hypot(Rc02, Rc12)``, ``theta6`` from the y column (exact for any
theta4, theta5, so it also serves the q5 = 0 hold); the wrist flip is
``(theta4 + pi, -theta5, theta6 + pi)``. Joints are ``q = sign * (theta - offset)``.

Trigonometric calls are avoided where an exact rational form exists: the
shoulder's cosine and sine are ``(cx u + cy b, cy u - cx b) / rho^2`` with ``u = +-t``, and
theta2 is one atan2 of the rotated vector.

Singular rows (flagged, the exact solution is still returned): ``h <
WRIST_SING_SIN`` (wrist), ``|sin psi| < ELBOW_SING_COS`` (arm stretched or
folded), ``t < SHOULDER_SING_MM`` (wrist centre on the axis-1 cylinder of
radius |b|: A1 undefined for b = 0, held by the solver).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fabric.robot.arm_family import cols_in_frame
from fabric.robot.kinematics import (
    ELBOW_SING_COS,
    SHOULDER_SING_MM,
    WRIST_SING_SIN,
    flip,
    wrap,
)
from fabric.robot.opw_derive import OPWParams

__all__ = ["OPWArm"]


class _Terms(NamedTuple):
    """Per-row inputs of one IK solve: wrist centre, its squared distance from axis 1, ``t``, held A1, columns."""

    cx: np.ndarray
    cy: np.ndarray
    cz: np.ndarray
    rho2: np.ndarray
    t: np.ndarray
    ok: np.ndarray
    th1_hold: np.ndarray | None
    C: np.ndarray


class OPWArm:
    """An OPW arm from :class:`~fabric.robot.opw_derive.OPWParams` (the ``ClosedFormArm`` interface)."""

    family = "opw"
    nq = 6
    free_joint = None          # 6 axes: no redundancy parameter (``q_free`` is ignored)

    def __init__(self, params: OPWParams) -> None:
        self.params = params
        pr = params
        self.a1, self.a2, self.b, self.c1 = pr.a1_mm, pr.a2_mm, pr.b_mm, pr.c1_mm
        self.c2, self.c3, self.c4 = pr.c2_mm, pr.c3_mm, pr.c4_mm
        self.k = float(np.hypot(self.a2, self.c3))
        self.phi = float(np.arctan2(self.a2, self.c3))
        self.off = np.asarray(pr.offsets_rad, dtype=float)
        self.sign = np.asarray(pr.signs, dtype=float)
        self.flange_T = np.asarray(pr.flange_T, dtype=float)
        B = np.asarray(pr.base_T, dtype=float)
        self._base: np.ndarray | None = None if np.allclose(B, np.eye(4), atol=1e-15, rtol=0) else B

    # Joint <-> model angles ------------------------------------------------
    def _theta(self, q: np.ndarray, j: int) -> np.ndarray:
        s, o = self.sign[j], self.off[j]
        return (q if s > 0 else -q) + o if o else (q if s > 0 else -q)

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
        t = [self._theta(q[:, j], j) for j in range(6)]
        c1, s1 = np.cos(t[0]), np.sin(t[0])
        c2, s2 = np.cos(t[1]), np.sin(t[1])
        c23, s23 = np.cos(t[1] + t[2]), np.sin(t[1] + t[2])
        c4, s4 = np.cos(t[3]), np.sin(t[3])
        c5, s5 = np.cos(t[4]), np.sin(t[4])
        c6, s6 = np.cos(t[5]), np.sin(t[5])
        # wrist rotation Rz(t4) Ry(t5) Rz(t6), rows of columns
        W = np.empty((len(q), 3, 3))
        W[:, 0, 0], W[:, 0, 1], W[:, 0, 2] = c4 * c5 * c6 - s4 * s6, -c4 * c5 * s6 - s4 * c6, c4 * s5
        W[:, 1, 0], W[:, 1, 1], W[:, 1, 2] = s4 * c5 * c6 + c4 * s6, -s4 * c5 * s6 + c4 * c6, s4 * s5
        W[:, 2, 0], W[:, 2, 1], W[:, 2, 2] = -s5 * c6, s5 * s6, c5
        # forearm frame Rz(t1) Ry(t23)
        Rc = np.empty((len(q), 3, 3))
        Rc[:, 0, 0], Rc[:, 0, 1], Rc[:, 0, 2] = c1 * c23, -s1, c1 * s23
        Rc[:, 1, 0], Rc[:, 1, 1], Rc[:, 1, 2] = s1 * c23, c1, s1 * s23
        Rc[:, 2, 0], Rc[:, 2, 1], Rc[:, 2, 2] = -s23, 0.0, c23
        R = Rc @ W
        cx1 = self.a1 + self.c2 * s2 + self.c3 * s23 + self.a2 * c23
        cz1 = self.c1 + self.c2 * c2 + self.c3 * c23 - self.a2 * s23
        T = np.zeros((len(q), 4, 4))
        T[:, :3, :3] = R
        T[:, 0, 3] = cx1 * c1 - self.b * s1 + self.c4 * R[:, 0, 2]
        T[:, 1, 3] = cx1 * s1 + self.b * c1 + self.c4 * R[:, 1, 2]
        T[:, 2, 3] = cz1 + self.c4 * R[:, 2, 2]
        T[:, 3, 3] = 1.0
        if self._base is not None:
            T = self._base @ T
        T = T @ self.flange_T
        return T[0] if single else T

    def point_xyz(self, q_rad: np.ndarray, v_mm: np.ndarray) -> np.ndarray:
        """Base-frame positions (N, 3) mm of the point ``v_mm`` (3,) of the flange frame, for joints (N, 6):
        :meth:`fk_flange`'s position of ``flange_T @ v``, without the rotations' products (a third of its
        time: the planner measures a million moves with it, ``fabric.planning.refine``)."""
        q = np.atleast_2d(np.asarray(q_rad, dtype=float))
        t = [self._theta(q[:, j], j) for j in range(6)]
        vx, vy, vz = (self.flange_T[:3, :3] @ np.asarray(v_mm, dtype=float) + self.flange_T[:3, 3]).tolist()
        vz += self.c4
        c6, s6 = np.cos(t[5]), np.sin(t[5])
        x6, y6 = c6 * vx - s6 * vy, s6 * vx + c6 * vy                   # Rz(t6)
        c5, s5 = np.cos(t[4]), np.sin(t[4])
        x5, z5 = c5 * x6 + s5 * vz, c5 * vz - s5 * x6                   # Ry(t5)
        c4, s4 = np.cos(t[3]), np.sin(t[3])
        x4, y4 = c4 * x5 - s4 * y6, s4 * x5 + c4 * y6                   # Rz(t4)
        t23 = t[1] + t[2]
        c23, s23 = np.cos(t23), np.sin(t23)
        xa, za = c23 * x4 + s23 * z5, c23 * z5 - s23 * x4               # Ry(t23)
        cx1 = self.a1 + self.c2 * np.sin(t[1]) + self.c3 * s23 + self.a2 * c23 + xa
        c1, s1 = np.cos(t[0]), np.sin(t[0])
        out = np.empty((len(q), 3))
        out[:, 0] = cx1 * c1 - (self.b + y4) * s1                       # Rz(t1)
        out[:, 1] = cx1 * s1 + (self.b + y4) * c1
        out[:, 2] = self.c1 + self.c2 * np.cos(t[1]) + self.c3 * c23 - self.a2 * s23 + za
        if self._base is not None:
            out = out @ self._base[:3, :3].T + self._base[:3, 3]
        return out

    # Inverse kinematics ----------------------------------------------------
    def native_constants(self) -> list[float]:
        """armik.c's ``opw_branch`` constants: a1, a2, b, c1, c2, c3, c4, k, phi."""
        return [float(v) for v in (self.a1, self.a2, self.b, self.c1, self.c2, self.c3, self.c4, self.k, self.phi)]

    def model_cols(self, C: np.ndarray) -> np.ndarray:
        """End-frame columns in the OPW base (the URDF base unless axis 1 is placed otherwise)."""
        return cols_in_frame(self._base, C)

    def _centre(self, C: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return C[0] - self.c4 * C[3], C[1] - self.c4 * C[4], C[2] - self.c4 * C[5]

    def q1_free(self, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A1 of the front shoulder per row, and the rows where it is undefined (centre on axis 1, b = 0)."""
        cx, cy, _ = self._centre(self.model_cols(C))
        rho2 = cx * cx + cy * cy
        t = np.sqrt(np.maximum(rho2 - self.b * self.b, 0.0))
        th1 = np.arctan2(cy * t - cx * self.b, cx * t + cy * self.b)
        degen = rho2 < 1e-12 if self.b == 0.0 else np.zeros(len(cx), dtype=bool)
        return self._q(th1, 0), degen

    def ik_branches_cols(self, C: np.ndarray, q1_hold: np.ndarray | None = None,
                         q_free: float | np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All 8 branches of end-frame columns ``C`` (9, N): ``q (N, 8, 6), reach (N, 8), singular (N, 8)``."""
        F = self._terms(self.model_cols(C), q1_hold)
        n = C.shape[1]
        qt = np.empty((8, 6, n))
        reach = np.empty((n, 8), dtype=bool)
        sing = np.empty((n, 8), dtype=bool)
        for b in range(0, 8, 2):
            th, ok, sg, _ = self._solve(F, b // 4, (b // 2) % 2)
            for w in range(2):
                for j, col in enumerate(_wrist_variant(th, w)):
                    qt[b + w, j] = self._q(col, j)
            reach[:, b:b + 2] = ok[:, None]
            sing[:, b:b + 2] = sg[:, None]
        return qt.transpose(2, 0, 1), reach, sing

    def ik_branch_cols(self, C: np.ndarray, branch: int, q1_hold: np.ndarray | None = None,
                       q_free: float | np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One branch for every row: ``q (6, N), reach, singular, gap_rad`` (see ``arm_family``)."""
        th, ok, sg, gap = self._solve(self._terms(self.model_cols(C), q1_hold), branch // 4, (branch // 2) % 2)
        q = np.empty((6, C.shape[1]))
        for j, col in enumerate(_wrist_variant(th, branch % 2)):
            q[j] = self._q(col, j)
        return q, ok, sg, gap

    def _terms(self, C: np.ndarray, q1_hold: np.ndarray | None) -> _Terms:
        """Per-row inputs of :meth:`_solve`."""
        cx, cy, cz = self._centre(C)
        rho2 = cx * cx + cy * cy
        t = np.sqrt(np.maximum(rho2 - self.b * self.b, 0.0))
        ok = rho2 >= self.b * self.b
        th1 = None if q1_hold is None else wrap(self._theta(np.asarray(q1_hold, dtype=float), 0))
        return _Terms(cx, cy, cz, rho2, t, ok, th1, C)

    def _solve(self, F: _Terms, shoulder: int, elbow: int
               ) -> tuple[tuple[np.ndarray, ...], np.ndarray, np.ndarray, np.ndarray]:
        """Model angles theta1..6 of one shoulder/elbow choice (wrist 0), reach, singular, gap to other branches."""
        cx, cy, cz, rho2, t, ok_s, th1h, C = F
        zx, zy, zz, yx, yy, yz = C[3], C[4], C[5], C[6], C[7], C[8]
        b = self.b
        if th1h is None:
            inv = 1.0 / np.where(rho2 > 0.0, rho2, 1.0)
            ts = -t if shoulder else t                      # the centre at (ts, b) in the arm's plane
            c1 = (cx * ts + cy * b) * inv
            s1 = (cy * ts - cx * b) * inv
            th1 = np.arctan2(s1, c1)
            u = (-t if shoulder else t) - self.a1
        else:
            th1 = flip(th1h) if shoulder else th1h
            c1, s1 = np.cos(th1), np.sin(th1)
            u = c1 * cx + s1 * cy - self.a1
        v = cz - self.c1
        c2, k = self.c2, self.k
        D = (u * u + v * v - c2 * c2 - k * k) / (2.0 * c2 * k)
        ok = ok_s & (np.abs(D) <= 1.0 + 1e-12)
        Dc = np.clip(D, -1.0, 1.0)
        sabs = np.sqrt(np.maximum(0.0, 1.0 - Dc * Dc))
        spsi = -sabs if elbow else sabs
        A, Bk = c2 + k * Dc, k * spsi
        th2 = np.arctan2(u * A - v * Bk, v * A + u * Bk)
        th3 = np.arctan2(spsi, Dc)
        if self.phi:
            th3 = wrap(th3 - self.phi)
        th23 = th2 + th3
        c23, s23 = np.cos(th23), np.sin(th23)
        # z and y columns of Rc = Ry(t23)^T Rz(t1)^T R
        zx1, zy1 = c1 * zx + s1 * zy, c1 * zy - s1 * zx
        yx1, yy1 = c1 * yx + s1 * yy, c1 * yy - s1 * yx
        R02, R12, R22 = c23 * zx1 - s23 * zz, zy1, s23 * zx1 + c23 * zz
        R01, R11, R21 = c23 * yx1 - s23 * yz, yy1, s23 * yx1 + c23 * yz
        h = np.sqrt(R02 * R02 + R12 * R12)
        th4 = np.arctan2(R12, R02)
        th5 = np.arctan2(h, R22)
        th6 = np.arctan2(h * h * R21 - R22 * (R02 * R01 + R12 * R11), R02 * R11 - R12 * R01)
        near = np.flatnonzero(h < 1e-3)
        if len(near):
            th6[near] = _zyz_theta6(R01[near], R11[near], R21[near], th4[near], th5[near])
        sing = (h < WRIST_SING_SIN) | (sabs < ELBOW_SING_COS) | (t < SHOULDER_SING_MM)
        gap = 2.0 * np.arctan2(sabs, np.abs(Dc))              # theta3 between the two elbows, wrapped
        if b:
            gap = np.minimum(gap, 2.0 * np.arctan2(t, abs(b)))  # theta1 between the two shoulders
        return (th1, th2, th3, th4, th5, th6), ok, sing, gap

    # Wrist singularity -----------------------------------------------------
    def wrist_sin(self, q: np.ndarray) -> np.ndarray:
        """``|sin theta5|`` of joints (6, N): 0 at the wrist singularity (axes 4 and 6 parallel)."""
        return np.abs(np.sin(self._theta(q[4], 4)))

    def wrist_degenerate(self, q: np.ndarray) -> np.ndarray:
        """Rows of joints (6, N) with sin(theta5) = 0: only theta4 + theta6 (or their difference) is defined."""
        return np.abs(np.sin(self._theta(q[4], 4))) < 1e-9

    def resolve_wrist(self, C: np.ndarray, q: np.ndarray, held: np.ndarray) -> np.ndarray:
        """Hold A4 at ``held[3]`` and solve A6 exactly on wrist-degenerate rows (6, M)."""
        Cm = self.model_cols(C)
        th = [self._theta(q[j], j) for j in range(6)]
        th4 = self._theta(held[3], 3)
        c1, s1 = np.cos(th[0]), np.sin(th[0])
        c23, s23 = np.cos(th[1] + th[2]), np.sin(th[1] + th[2])
        yx, yy, yz = Cm[6], Cm[7], Cm[8]
        yx1, yy1 = c1 * yx + s1 * yy, c1 * yy - s1 * yx
        R01, R11, R21 = c23 * yx1 - s23 * yz, yy1, s23 * yx1 + c23 * yz
        out = q.copy()
        out[3] = held[3]
        out[5] = self._q(_zyz_theta6(R01, R11, R21, th4, th[4]), 5)
        return out


def _wrist_variant(th: tuple[np.ndarray, ...], wrist: int) -> tuple[np.ndarray, ...]:
    """The wrist-flipped angles (theta4 + pi, -theta5, theta6 + pi) when ``wrist`` is 1."""
    if not wrist:
        return th
    t1, t2, t3, t4, t5, t6 = th
    return t1, t2, t3, flip(t4), -t5, flip(t6)


def _zyz_theta6(R01: np.ndarray, R11: np.ndarray, R21: np.ndarray, th4: np.ndarray, th5: np.ndarray) -> np.ndarray:
    """theta6 from the y column of ``Rz(t4) Ry(t5) Rz(t6)``: exact for any theta4, theta5."""
    c4, s4, c5, s5 = np.cos(th4), np.sin(th4), np.cos(th5), np.sin(th5)
    return np.arctan2(s5 * R21 - c5 * (c4 * R01 + s4 * R11), c4 * R11 - s4 * R01)
