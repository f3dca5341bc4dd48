"""The UR-type description of an arm (Denavit-Hartenberg lengths, joint offsets and signs), read from its axes at zero.

A UR-type arm (Universal Robots, and the many cobots copied from it) has axis 1
vertical, meeting axis 2 at right angles; axes 2, 3 and 4 parallel (a planar
shoulder-elbow-wrist-1 chain with links ``a2`` and ``a3``); axis 5 meeting
axis 4 at right angles and axis 6 meeting axis 5 at right angles: an offset
wrist, not a spherical one. Its standard DH table is

    joint  theta  d    a    alpha
    1      t1     d1   0    +90 deg
    2      t2     0    a2   0
    3      t3     0    a3   0
    4      t4     d4   0    +90 deg
    5      t5     d5   0    -90 deg
    6      t6     d6   0    0

(``d4`` collects every sideways offset of the parallel axes), and a URDF joint
relates to it by ``theta_i = sign_i * q_i + offset_i``. Everything is read off
the joint axes at ``q = 0`` (``joint_axes.py``) in a frame with z along axis 1
(``opw_derive.axis_base_T``): ``d1`` is where axes 1 and 2 meet; the DH ``z1``
is axis 2's direction (so ``sign_2 = +1``), which fixes ``offset_1``; ``a2``,
``a3`` and their angles are the distances between the parallel axes in the arm
plane (both positive; the angles go into ``offset_2``, ``offset_3``); ``d4`` is
where axis 5 meets axis 4, measured along axis 2; axis 5 fixes ``offset_4``,
axis 6 ``offset_5``; ``d5`` and ``d6`` are the steps along axes 5 and 6, and
``flange_T`` maps the DH frame 6 to the URDF flange (``offset_6 = 0``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabric.robot.arm_family import ANG_TOL, DIST_TOL_MM, IKFamilyMismatch
from fabric.robot.frames import make_T
from fabric.robot.joint_axes import JointAxes, line_closest_points, line_distance_mm
from fabric.robot.opw_derive import axis_base_T, clean_mm, clean_rad, six_revolute

__all__ = ["URParams", "derive_ur", "ur_dh_frames"]


@dataclass(frozen=True)
class URParams:
    """UR DH lengths (mm), ``theta = sign * q + offset`` per joint, and the frames that place the model."""

    d1_mm: float
    a2_mm: float
    a3_mm: float
    d4_mm: float
    d5_mm: float
    d6_mm: float
    offsets_rad: tuple[float, ...]
    signs: tuple[float, ...]
    base_T: np.ndarray         # DH base frame in the URDF base frame
    flange_T: np.ndarray       # DH frame 6 -> URDF flange

    def lengths_mm(self) -> dict[str, float]:
        """The DH lengths by their usual names."""
        return {"d1": self.d1_mm, "a2": self.a2_mm, "a3": self.a3_mm, "d4": self.d4_mm,
                "d5": self.d5_mm, "d6": self.d6_mm}


def ur_dh_frames(th: list[np.ndarray], d1: float, a2: float, a3: float, d4: float, d5: float, d6: float
                 ) -> tuple[np.ndarray, ...]:
    """Axes ``x6, y6, z6`` and origin ``p6`` (each (N, 3)) of the DH frame 6 for model angles ``th``.

    Frame 1 has ``x1`` radial, ``y1`` up, ``z1`` along axis 2; the planar
    chain puts axis 4 at ``X x1 + Y y1`` from ``(0, 0, d1)``; frame 4 has
    ``x4 = c234 x1 + s234 y1``, ``y4 = z1``, ``z4 = s234 x1 - c234 y1`` (axis
    5); frame 5 ``x5 = c5 x4 + s5 y4``, ``y5 = -z4``, ``z5 = -s5 x4 + c5 y4``
    (axis 6); frame 6 turns frame 5 by theta6 about z5.
    """
    c1, s1 = np.cos(th[0]), np.sin(th[0])
    t23 = th[1] + th[2]
    t234 = t23 + th[3]
    X = a2 * np.cos(th[1]) + a3 * np.cos(t23)
    Y = a2 * np.sin(th[1]) + a3 * np.sin(t23)
    c234, s234 = np.cos(t234), np.sin(t234)
    c5, s5 = np.cos(th[4]), np.sin(th[4])
    c6, s6 = np.cos(th[5]), np.sin(th[5])
    zero = np.zeros_like(c1)
    x1 = np.stack([c1, s1, zero], axis=-1)
    y1 = np.stack([zero, zero, zero + 1.0], axis=-1)
    z1 = np.stack([s1, -c1, zero], axis=-1)
    x4 = c234[..., None] * x1 + s234[..., None] * y1
    z4 = s234[..., None] * x1 - c234[..., None] * y1
    x5 = c5[..., None] * x4 + s5[..., None] * z1
    z5 = -s5[..., None] * x4 + c5[..., None] * z1
    y5 = -z4
    x6 = c6[..., None] * x5 + s6[..., None] * y5
    y6 = -s6[..., None] * x5 + c6[..., None] * y5
    p = (X[..., None] * x1 + (Y + d1)[..., None] * y1 + d4 * z1 + d5 * z4 + d6 * z5)
    return x6, y6, z5, p


def _perp(w: np.ndarray, i: int, j: int) -> None:
    if abs(w[i] @ w[j]) > ANG_TOL:
        raise IKFamilyMismatch("ur", f"axis {j + 1} is not perpendicular to axis {i + 1}", abs(float(w[i] @ w[j])))


def _meet(w: np.ndarray, p: np.ndarray, i: int, j: int) -> np.ndarray:
    a, b = line_closest_points(p[i], w[i], p[j], w[j])
    if np.linalg.norm(a - b) > DIST_TOL_MM:
        raise IKFamilyMismatch("ur", f"axes {i + 1} and {j + 1} do not meet (distance, mm)",
                               float(np.linalg.norm(a - b)))
    return 0.5 * (a + b)


def _check_structure(w: np.ndarray, p: np.ndarray) -> None:
    """The UR conditions on the axes (any frame)."""
    _perp(w, 0, 1)
    _meet(w, p, 0, 1)
    for j in (2, 3):
        if np.linalg.norm(np.cross(w[1], w[j])) > ANG_TOL:
            raise IKFamilyMismatch("ur", f"axis {j + 1} is not parallel to axis 2 (a UR-type arm has three "
                                         f"parallel axes 2, 3, 4)", float(np.linalg.norm(np.cross(w[1], w[j]))))
    for i, j in ((1, 2), (2, 3)):
        if line_distance_mm(p[i], w[i], p[j], w[j]) < DIST_TOL_MM:
            raise IKFamilyMismatch("ur", f"axes {i + 1} and {j + 1} coincide (no link between them)")
    for i, j in ((3, 4), (4, 5)):
        _perp(w, i, j)
        _meet(w, p, i, j)


def derive_ur(ax: JointAxes) -> URParams:
    """The UR-type description of an arm from its axes (module docstring), or :class:`IKFamilyMismatch`."""
    six_revolute(ax, "ur")
    _check_structure(ax.directions, ax.points_mm)
    B = axis_base_T(ax)
    RB, tB = B[:3, :3], B[:3, 3]
    w = ax.directions @ RB
    p = (ax.points_mm - tB) @ RB
    M = np.linalg.inv(B) @ ax.flange_T
    s1 = -1.0 if w[0][2] < 0.0 else 1.0
    p12 = _meet(w, p, 0, 1)
    d1 = float(p12[2])
    z1 = w[1]
    o1 = float(np.arctan2(z1[0], -z1[1]))
    x1 = np.array([np.cos(o1), np.sin(o1), 0.0])
    y1 = np.array([0.0, 0.0, 1.0])
    s3 = -1.0 if w[2] @ z1 < 0.0 else 1.0
    s4 = -1.0 if w[3] @ z1 < 0.0 else 1.0

    def planar(P: np.ndarray) -> np.ndarray:
        return np.array([(P - p12) @ x1, (P - p12) @ y1])

    P3, P4 = planar(p[2]), planar(p[3])
    a2, o2 = float(np.hypot(*P3)), float(np.arctan2(P3[1], P3[0]))
    d34 = P4 - P3
    a3, t23 = float(np.hypot(*d34)), float(np.arctan2(d34[1], d34[0]))
    p45 = _meet(w, p, 3, 4)
    d4 = float((p45 - p12) @ z1)
    z4 = w[4]
    t234 = float(np.arctan2(z4 @ x1, -(z4 @ y1)))
    x4 = np.cos(t234) * x1 + np.sin(t234) * y1
    o5 = float(np.arctan2(-(w[5] @ x4), w[5] @ z1))
    p56 = _meet(w, p, 4, 5)
    d5 = float((p56 - p45) @ z4)
    d6 = float((M[:3, 3] - p56) @ w[5])
    if abs(d6) < 1e-3:
        raise IKFamilyMismatch("ur", "the flange lies on axis 5 (d6 = 0): the wrist cannot be solved in closed form")
    offsets = tuple(clean_rad(o) for o in (o1, o2, t23 - o2, t234 - t23, o5, 0.0))
    lengths = dict(d1=clean_mm(d1), a2=a2, a3=a3, d4=clean_mm(d4), d5=clean_mm(d5), d6=d6)
    x6, y6, z6, p6 = ur_dh_frames([np.array(o) for o in offsets], *lengths.values())
    E = make_T(np.column_stack([x6, y6, z6]), p6)
    return URParams(d1_mm=lengths["d1"], a2_mm=a2, a3_mm=a3, d4_mm=lengths["d4"], d5_mm=lengths["d5"], d6_mm=d6,
                    offsets_rad=offsets, signs=(s1, 1.0, s3, s4, 1.0, 1.0), base_T=B, flange_T=np.linalg.inv(E) @ M)
