"""Closed-form, vectorised kinematics of a spherical-wrist 6R arm (the ABB IRB 140), plus IK status codes.

Geometry (mm, ABB joint signs, see ``robots/irb140.urdf``): A1 turns about the
base z axis; the shoulder (A2) sits ``a1`` forward and ``d1`` up; the upper arm
(``a2``) is vertical at zero; the forearm leaves the elbow (A3) along +x (``d4``
to the wrist centre, ``a3`` above the elbow axis: 0 on the IRB 140); A4, A5, A6
meet at the wrist centre; the flange is ``d6`` beyond it. A2, A3 and A5 turn
about +y (positive = forward / down), A1 about +z, A4 and A6 about the forearm /
flange axis. Flange frame: z out of the flange, x pointing down at zero.

Inverse kinematics is the spherical-wrist decomposition: the wrist centre
``c = p_flange - d6 * z_flange`` fixes A1 (facing the target, or turned 180 deg
and reaching back over the top), then A2/A3 by the law of cosines in the arm
plane (elbow up / down), then ``R36 = R03^T R06 = Rx(q4) Ry(q5) Rx(q6)`` gives the
wrist (q5 or -q5: the wrist flip). All 8 branches are arrays ``(N, 8, 6)``,
branch ``b = 4*shoulder + 2*elbow + wrist``.

Branch choice (``select_branches``): row i takes, among its valid branches, the
one nearest (joint-space distance, angles compared modulo 2*pi) the solution
chosen for row i-1; row 0 the one nearest the seed. Written as a map
``nxt[i, b]`` ("best branch at row i if row i-1 used b") the sequential part is
only the chain ``b_i = nxt[i, b_{i-1}]``. ``nxt[i]`` is the identity whenever
every branch moved less than half the smallest distance between two branches of
row i (triangle inequality), and that separation is known in closed form:
branches differing in shoulder or wrist differ by pi in A1 or A4; branches
differing in elbow differ by ``pi - 2|psi|`` in A3 (small only near the stretched
elbow). So a cheap per-row test marks the "quiet" rows, the full 8x8 distances
are computed only for the others, and a Python loop follows the chain through
those few rows: on a smooth toolpath that is a handful, not N. Multi-turn joints
(range >= 360 deg: A1, A4, A6) are finally unwrapped towards the previous row
and shifted by 2*pi back into their limits if a wind-up would leave them.

Singularities, flagged ``IK_SINGULAR`` (the exact solution is still returned):
the Jacobian determinant factors as ``a2 * L * cos(psi) * rho * sin(q5)`` (``L``
forearm length, ``psi`` the elbow angle from the stretched-out forearm, ``rho``
the wrist centre's distance from the A1 axis), so a row is singular when
``|sin q5| < WRIST_SING_SIN`` (0.01: wrist rates 100x the TCP rate),
``|cos psi| < ELBOW_SING_COS`` (0.01: arm stretched or folded) or
``rho < SHOULDER_SING_MM`` (10 mm). Where q5 is exactly 0 only q4 + q6 is
defined: q4 is held at the previous row's value and q6 solved; where the wrist
centre is exactly on the A1 axis, A1 is held likewise.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "IK_OK", "IK_OUT_OF_REACH", "IK_JOINT_LIMIT", "IK_SINGULAR", "IK_JUMP", "IK_REASONS", "ik_reason",
    "WRIST_SING_SIN", "ELBOW_SING_COS", "SHOULDER_SING_MM", "SphericalWristArm", "IRB140_ARM",
    "multi_turn_mask", "wrist_q6", "pose_cols", "wrap", "wrap_diff", "flip", "LIMIT_TOL_RAD", "PI", "TWO_PI",
]

IK_OK, IK_OUT_OF_REACH, IK_JOINT_LIMIT, IK_SINGULAR, IK_JUMP = 0, 1, 2, 3, 4
# The one map from IK status codes to words; every failing status names an UnreachableError reason.
IK_REASONS: dict[int, str] = {
    IK_OK: "ok",
    IK_OUT_OF_REACH: "out of reach",
    IK_JOINT_LIMIT: "joint limit",
    IK_SINGULAR: "singular",
    IK_JUMP: "joint jump",
}


def ik_reason(status: int | np.integer) -> str:
    """The ``UnreachableError`` reason (``fabric.wire.errors.UNREACHABLE_REASONS``) of a failing IK status."""
    code = int(status)
    if code == IK_OK or code not in IK_REASONS:
        raise ValueError(f"IK status {code} is not a failure (statuses: {IK_REASONS})")
    return IK_REASONS[code]


WRIST_SING_SIN = 0.01
ELBOW_SING_COS = 0.01
SHOULDER_SING_MM = 10.0
LIMIT_TOL_RAD = 1e-9      # a joint this far past a limit is at it (rounding): in limits, on either side
TWO_PI = 2.0 * np.pi
PI = np.pi


def wrap(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-pi, pi]."""
    return a - TWO_PI * np.rint(a / TWO_PI)


def wrap_diff(d: np.ndarray) -> np.ndarray:
    """Differences of two angles in [-pi, pi] (so d in [-2*pi, 2*pi]) wrapped to [-pi, pi]."""
    d = np.where(d > PI, d - TWO_PI, d)
    return np.where(d < -PI, d + TWO_PI, d)


def flip(a: np.ndarray) -> np.ndarray:
    """``wrap(a + pi)`` for a in [-pi, pi], without a modulo."""
    return np.where(a >= 0.0, a - PI, a + PI)


def multi_turn_mask(lower_rad: np.ndarray, upper_rad: np.ndarray) -> np.ndarray:
    """Joints whose range spans a full turn: IK only defines their angle modulo 2*pi."""
    return (np.asarray(upper_rad) - np.asarray(lower_rad)) >= TWO_PI - 1e-9


@dataclass(frozen=True)
class SphericalWristArm:
    """Link lengths (mm) of an ABB-style 6R arm with a spherical wrist (see module docstring).

    The reference the OPW family (``fabric/robot/opw.py``) is tested against; it
    has the ``ClosedFormArm`` interface of ``fabric/robot/arm_family.py`` with
    its flange as the end frame.
    """

    d1_mm: float
    a1_mm: float
    a2_mm: float
    a3_mm: float
    d4_mm: float
    d6_mm: float
    family = "abb-spherical-wrist"
    nq = 6
    free_joint = None          # 6 axes: no redundancy parameter (``q_free`` is ignored)

    @property
    def flange_T(self) -> np.ndarray:
        """End frame -> flange: the identity (this model's end frame is the flange)."""
        return np.eye(4)

    def q1_free(self, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A1 facing the wrist centre, and the rows where the centre is on the A1 axis."""
        wx, wy = C[0] - self.d6_mm * C[3], C[1] - self.d6_mm * C[4]
        return np.arctan2(wy, wx), wx * wx + wy * wy < 1e-12

    def wrist_sin(self, q: np.ndarray) -> np.ndarray:
        """``|sin q5|`` of joints (6, N): 0 at the wrist singularity."""
        return np.abs(np.sin(q[4]))

    def wrist_degenerate(self, q: np.ndarray) -> np.ndarray:
        """Rows of joints (6, N) with q5 exactly 0 (only q4 + q6 is defined)."""
        return np.abs(np.sin(q[4])) < 1e-9

    def resolve_wrist(self, C: np.ndarray, q: np.ndarray, held: np.ndarray) -> np.ndarray:
        """Hold A4 at ``held[3]`` and solve A6 exactly from ``R36 = R03^T R06``."""
        z, y = C[3:6].T, C[6:9].T
        R06 = np.stack([z, y, -np.cross(y, z)], axis=-1)
        c1, s1 = np.cos(q[0]), np.sin(q[0])
        c, s = np.cos(q[1] + q[2]), np.sin(q[1] + q[2])
        R03 = np.zeros((q.shape[1], 3, 3))
        R03[:, 0, 0], R03[:, 0, 1], R03[:, 0, 2] = c1 * c, -s1, c1 * s
        R03[:, 1, 0], R03[:, 1, 1], R03[:, 1, 2] = s1 * c, c1, s1 * s
        R03[:, 2, 0], R03[:, 2, 2] = -s, c
        R36 = np.swapaxes(R03, 1, 2) @ R06
        out = q.copy()
        out[3] = held[3]
        out[5] = wrist_q6(R36[:, 0, 1], R36[:, 1, 1], R36[:, 2, 1], held[3], q[4])
        return out

    def fk_flange(self, q_rad: np.ndarray) -> np.ndarray:
        """Flange poses (N, 4, 4) in mm for joints (N, 6); (4, 4) for (6,)."""
        q = np.asarray(q_rad, dtype=float)
        single = q.ndim == 1
        q = np.atleast_2d(q)
        c1, s1 = np.cos(q[:, 0]), np.sin(q[:, 0])
        c2, s2 = np.cos(q[:, 1]), np.sin(q[:, 1])
        c23, s23 = np.cos(q[:, 1] + q[:, 2]), np.sin(q[:, 1] + q[:, 2])
        ca, sa = np.cos(q[:, 3]), np.sin(q[:, 3])
        cb, sb = np.cos(q[:, 4]), np.sin(q[:, 4])
        cc, sc = np.cos(q[:, 5]), np.sin(q[:, 5])
        # wrist centre: radial r and height z in the arm plane
        r = self.a1_mm + self.a2_mm * s2 + self.d4_mm * c23 + self.a3_mm * s23
        z = self.d1_mm + self.a2_mm * c2 - self.d4_mm * s23 + self.a3_mm * c23
        # R36 = Rx(q4) Ry(q5) Rx(q6), columns k = 0, 1, 2 as (x, y, z) rows of the arm plane
        cols = (
            (cb, sa * sb, -ca * sb),
            (sb * sc, ca * cc - sa * cb * sc, sa * cc + ca * cb * sc),
            (sb * cc, -ca * sc - sa * cb * cc, -sa * sc + ca * cb * cc),
        )
        T = np.zeros((4, 4, len(q)))                      # filled row-contiguous, returned as (N, 4, 4)
        # R06 = Rz(q1) Ry(q23) R36; flange = link 6 turned +90 deg about y: z_f = x6, y_f = y6, x_f = -z6
        for k, dst, sign in ((0, 2, 1.0), (1, 1, 1.0), (2, 0, -1.0)):
            x3, y3, z3 = cols[k]
            xa = c23 * x3 + s23 * z3
            za = -s23 * x3 + c23 * z3
            T[0, dst] = sign * (c1 * xa - s1 * y3)
            T[1, dst] = sign * (s1 * xa + c1 * y3)
            T[2, dst] = sign * za
        T[0, 3] = c1 * r + self.d6_mm * T[0, 2]
        T[1, 3] = s1 * r + self.d6_mm * T[1, 2]
        T[2, 3] = z + self.d6_mm * T[2, 2]
        T[3, 3] = 1.0
        T = np.ascontiguousarray(T.transpose(2, 0, 1))
        return T[0] if single else T

    def ik_branches(self, T_flange: np.ndarray, q1_hold: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All 8 IK branches of flange poses (N, 4, 4) mm.

        Returns ``q`` (N, 8, 6), angles in [-pi, pi], ``reach`` (N, 8) True
        where the branch is a real solution and ``sing`` (N, 8) True where it
        is singular. ``q1_hold`` (N,) imposes A1 (and A1 + pi for the back
        shoulder) instead of ``atan2`` of the wrist centre.
        """
        return self.ik_branches_cols(pose_cols(T_flange), q1_hold)

    def ik_branches_cols(self, C: np.ndarray, q1_hold: np.ndarray | None = None,
                         q_free: float | np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`ik_branches` of flange poses given as columns ``C`` (9, N) (see :func:`pose_cols`)."""
        F = self._terms(C, q1_hold)
        n = C.shape[1]
        qt = np.empty((8, 6, n))                          # filled row-contiguous, returned as (n, 8, 6)
        reach = np.empty((n, 8), dtype=bool)
        sing = np.empty((n, 8), dtype=bool)
        for b in range(0, 8, 2):
            cols, ok, sg, _ = self._solve(F, b // 4, (b // 2) % 2)
            for w in range(2):
                for j, col in enumerate(_wrist_variant(cols, w)):
                    qt[b + w, j] = col
            reach[:, b:b + 2] = ok[:, None]
            sing[:, b:b + 2] = sg[:, None]
        return qt.transpose(2, 0, 1), reach, sing

    def ik_branch(self, T_flange: np.ndarray, branch: int, q1_hold: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One branch for every row: ``q (N, 6), reach (N,), singular (N,), elbow_gap_rad (N,)``.

        ``elbow_gap_rad`` is the A3 distance to the other elbow branch (the
        smallest separation between this branch and any other, capped at pi).
        """
        q, ok, sg, gap = self.ik_branch_cols(pose_cols(T_flange), branch, q1_hold)
        return q.T, ok, sg, gap

    def ik_branch_cols(self, C: np.ndarray, branch: int, q1_hold: np.ndarray | None = None,
                       q_free: float | np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`ik_branch` of flange columns ``C`` (9, N); joints returned as columns ``(6, N)``."""
        cols, ok, sg, gap = self._solve(self._terms(C, q1_hold), branch // 4, (branch // 2) % 2)
        q = np.empty((6, C.shape[1]))
        for j, col in enumerate(_wrist_variant(cols, branch % 2)):
            q[j] = col
        return q, ok, sg, gap

    def _terms(self, C: np.ndarray, q1_hold: np.ndarray | None) -> tuple[np.ndarray, ...]:
        """Per-row inputs of :meth:`_solve`: flange z and y columns, wrist centre, A1."""
        px, py, pz, zx, zy, zz, yx, yy, yz = C
        d6 = self.d6_mm
        wx, wy = px - d6 * zx, py - d6 * zy
        v = pz - d6 * zz - self.d1_mm
        q1 = np.arctan2(wy, wx) if q1_hold is None else wrap(np.asarray(q1_hold, dtype=float))
        return (zx, zy, zz, yx, yy, yz, wx, wy, v, q1,
                wx * wx + wy * wy < SHOULDER_SING_MM * SHOULDER_SING_MM)

    def _solve(self, F: tuple[np.ndarray, ...], shoulder: int, elbow: int
               ) -> tuple[tuple[np.ndarray, ...], np.ndarray, np.ndarray, np.ndarray]:
        """q1..q6 of one shoulder/elbow choice (wrist 0), reach, singular, elbow gap."""
        zx, zy, zz, yx, yy, yz, wx, wy, v, q1, shoulder_sing = F
        L = float(np.hypot(self.d4_mm, self.a3_mm))
        phi = float(np.arctan2(self.a3_mm, self.d4_mm))
        if shoulder:
            q1 = flip(q1)
        c1, s1 = np.cos(q1), np.sin(q1)
        # the flange z and y columns expressed in the arm plane: Rz(-q1) applied
        zx1, zy1 = c1 * zx + s1 * zy, c1 * zy - s1 * zx
        yx1, yy1 = c1 * yx + s1 * yy, c1 * yy - s1 * yx
        u = c1 * wx + s1 * wy - self.a1_mm
        k = (self.a2_mm ** 2 + L * L - u * u - v * v) / (2.0 * self.a2_mm * L)
        ok = np.abs(k) <= 1.0 + 1e-12
        kc = np.clip(k, -1.0, 1.0)
        cabs = np.sqrt(np.maximum(0.0, 1.0 - kc * kc))
        cpsi = -cabs if elbow else cabs
        A, B = self.a2_mm - L * kc, L * cpsi
        q2 = np.arctan2(A * u - B * v, A * v + B * u)
        q3 = np.arctan2(kc, cpsi)
        if phi:
            q3 = wrap(q3 + phi)
        q23 = q2 + q3
        c23, s23 = np.cos(q23), np.sin(q23)
        # first two columns of R36 = Ry(q23)^T (Rz(q1)^T R06)
        R00, R10, R20 = c23 * zx1 - s23 * zz, zy1, s23 * zx1 + c23 * zz
        R01, R11, R21 = c23 * yx1 - s23 * yz, yy1, s23 * yx1 + c23 * yz
        h = np.sqrt(R10 * R10 + R20 * R20)
        q4 = np.arctan2(R10, -R20)
        q5 = np.arctan2(h, R00)
        # q6 with cos/sin q4 = -R20/h, R10/h and sin q5 = h, all scaled by h (no division)
        q6 = np.arctan2(h * h * R01 - R00 * (R10 * R11 + R20 * R21), R10 * R21 - R20 * R11)
        near = np.flatnonzero(h < 1e-3)
        if len(near):
            q6[near] = wrist_q6(R01[near], R11[near], R21[near], q4[near], q5[near])
        sing = (h < WRIST_SING_SIN) | (cabs < ELBOW_SING_COS) | shoulder_sing
        gap = 2.0 * np.arctan2(cabs, np.abs(kc))        # |q3(elbow 0) - q3(elbow 1)| wrapped
        return (q1, q2, q3, q4, q5, q6), ok, sing, gap


def pose_cols(T: np.ndarray, post_T: np.ndarray | None = None) -> np.ndarray:
    """Poses (N, 4, 4) as columns (9, N): position, z axis, y axis of ``T @ post_T`` (mm).

    The IK reads only these nine numbers per pose (the x axis is ``y x z``); one
    matrix product over the flattened poses gathers them contiguously, applying
    ``post_T`` (a rigid transform, e.g. TCP -> flange) on the way. With no
    ``post_T`` the columns are copied exactly.
    """
    T = np.asarray(T, dtype=float).reshape(-1, 4, 4)
    if post_T is None:
        return np.ascontiguousarray(T.reshape(-1, 16)[:, _COLS].T)
    K = np.asarray(post_T, dtype=float)[:, [3, 2, 1]]          # (4, 3): point, z, y of post_T
    W = np.zeros((9, 16))
    for c in range(3):
        for i in range(3):
            W[3 * c + i, 4 * i:4 * i + 4] = K[:, c]
    return W @ T.reshape(-1, 16).T


_COLS = np.array([3, 7, 11, 2, 6, 10, 1, 5, 9])     # flat (4, 4) indices of p, z, y


def _wrist_variant(cols: tuple[np.ndarray, ...], wrist: int) -> tuple[np.ndarray, ...]:
    """The wrist-flipped solution (q4 + pi, -q5, q6 + pi) when ``wrist`` is 1."""
    if not wrist:
        return cols
    q1, q2, q3, q4, q5, q6 = cols
    return q1, q2, q3, flip(q4), -q5, flip(q6)


def wrist_q6(R01: np.ndarray, R11: np.ndarray, R21: np.ndarray, q4: np.ndarray, q5: np.ndarray) -> np.ndarray:
    """q6 from ``Rx(q6) = Ry(q5)^T Rx(q4)^T R36`` (column 1 of R36): exact for any q4, q5."""
    c4, s4, c5, s5 = np.cos(q4), np.sin(q4), np.cos(q5), np.sin(q5)
    return np.arctan2(s5 * R01 + c5 * (-s4 * R11 + c4 * R21), c4 * R11 + s4 * R21)


IRB140_ARM = SphericalWristArm(d1_mm=352.0, a1_mm=70.0, a2_mm=360.0, a3_mm=0.0, d4_mm=380.0, d6_mm=65.0)
"""The ABB IRB 140 from its public figures."""


# Branch selection along a path ------------------------------------------------
