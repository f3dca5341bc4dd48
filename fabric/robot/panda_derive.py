"""The Panda-type description of a 7-axis arm (shoulder point, elbow axis, wrist point, A7), read from its axes at zero.

A Panda-type arm (the Franka Emika Panda; the conditions also describe
"SRS" arms such as the KUKA iiwa, not tested here) has a **spherical
shoulder**: axes 1, 2 and 3 meet in one point ``S``, axis 2 perpendicular to
axes 1 and 3; an elbow axis 4 that passes neither through ``S`` nor through
the wrist point ``W``; axes 5 and 6 meeting at right angles in ``W``; and a
seventh axis anywhere (the Panda's is 88 mm off axis 6). With A7 given, the
flange pose fixes the whole link 6, so the six other joints are a 6R problem
in closed form (``panda.py``). Like the other families, the conditions are
exact (``arm_family.ANG_TOL``, ``DIST_TOL_MM``): a URDF whose angles are
rounded (the xArm 7 of example-robot-data has axis 2 3.7e-6 rad off square
to axis 1) is refused and gets the numeric IK.

Everything is read off the joint axes at ``q = 0`` (``joint_axes.py``) in the
product-of-exponentials form, so no Denavit-Hartenberg table and no joint
offsets are needed: joint i turns the rest of the arm about its line at zero.
The conditions, checked in this order (the first that fails is the error):
seven revolute joints; axis 1 perpendicular to axis 2; axes 1 and 2 meet;
axis 3 perpendicular to axis 2 and through that point (the shoulder); axes 5
and 6 meet, at right angles (the wrist point); axis 4 clear of the shoulder
and of the wrist point (else the elbow does not move the wrist relative to
the shoulder). The model base ``base_T`` has its origin at ``S``, z along
axis 1 and y along axis 2 (so A1 and A2 turn about the base z and y axes);
the end frame ``E`` has z along axis 7 and its origin on axis 7 nearest the
URDF flange, and ``flange_T`` maps it to the URDF flange (the identity for the
Panda's ``panda_link8``). The caller verifies the result against Pinocchio.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabric.robot.arm_family import ANG_TOL, DIST_TOL_MM, IKFamilyMismatch
from fabric.robot.frames import make_T
from fabric.robot.joint_axes import JointAxes, line_closest_points, line_distance_mm
from fabric.robot.opw_derive import clean_mm, clean_rad

__all__ = ["PandaParams", "derive_panda", "ELBOW_CLEAR_MM"]

FAMILY = "panda"
ELBOW_CLEAR_MM = 1e-3          # axis 4 must pass at least this far from the shoulder and the wrist point


@dataclass(frozen=True)
class PandaParams:
    """The arm's axes in its model base (origin at the shoulder), the end frame at zero and the frames placing them.

    ``directions`` and ``points_mm`` (7, 3): each joint's axis at ``q = 0`` in the
    model base, the point being the shoulder ``S`` (the origin) for axes 1-3,
    the elbow axis' foot on the common normal with axis 3 for axis 4, the
    wrist point ``W`` for axes 5 and 6, and the end frame's origin for axis 7.
    """

    directions: np.ndarray     # (7, 3) unit axes, model base
    points_mm: np.ndarray      # (7, 3)
    end_T: np.ndarray          # end frame at q = 0 in the model base (z along axis 7)
    base_T: np.ndarray         # model base in the URDF base frame
    flange_T: np.ndarray       # end frame -> URDF flange
    shoulder_mm: float         # S above the URDF base origin, along axis 1
    upper_arm_mm: float        # S to the common normal of axes 3 and 4, along axis 3 (Panda: d3 = 316)
    a4_mm: float               # distance between axes 3 and 4 (82.5)
    a5_mm: float               # distance between axes 4 and 5 (82.5)
    forearm_mm: float          # common normal of axes 4 and 5 to W, along axis 5 (d5 = 384)
    a7_mm: float               # distance between axes 6 and 7 (88)
    flange_mm: float           # common normal of axes 6 and 7 to the flange origin, along axis 7 (107)
    offset2_rad: float         # angle from axis 1 to axis 3 about axis 2 at zero (0: collinear)

    def lengths_mm(self) -> dict[str, float]:
        """The lengths by their Denavit-Hartenberg names on the Panda (for display)."""
        return {"d1": self.shoulder_mm, "d3": self.upper_arm_mm, "a4": self.a4_mm, "a5": self.a5_mm,
                "d5": self.forearm_mm, "a7": self.a7_mm, "dF": self.flange_mm}


def _perp(w: np.ndarray, i: int, j: int) -> None:
    if abs(w[i] @ w[j]) > ANG_TOL:
        raise IKFamilyMismatch(FAMILY, f"axis {j + 1} is not perpendicular to axis {i + 1}", abs(float(w[i] @ w[j])))


def _meet(w: np.ndarray, p: np.ndarray, i: int, j: int, what: str) -> np.ndarray:
    a, b = line_closest_points(p[i], w[i], p[j], w[j])
    if np.linalg.norm(a - b) > DIST_TOL_MM:
        raise IKFamilyMismatch(FAMILY, f"axes {i + 1} and {j + 1} do not meet ({what}; distance, mm)",
                               float(np.linalg.norm(a - b)))
    return 0.5 * (a + b)


def _off_line(point: np.ndarray, p: np.ndarray, w: np.ndarray) -> float:
    """Distance (mm) of ``point`` from the line ``p + t w``."""
    return float(np.linalg.norm(np.cross(point - p, w)))


def _check_structure(ax: JointAxes) -> tuple[np.ndarray, np.ndarray]:
    """The Panda-type conditions (module docstring); returns the shoulder and wrist points (URDF base, mm)."""
    if len(ax.kinds) != 7:
        raise IKFamilyMismatch(FAMILY, f"needs 7 joints, the URDF has {len(ax.kinds)}")
    if not ax.revolute.all():
        j = int(np.argmin(ax.revolute))
        raise IKFamilyMismatch(FAMILY, f"joint {j + 1} is not revolute ({ax.kinds[j]})")
    w, p = ax.directions, ax.points_mm
    _perp(w, 0, 1)
    S = _meet(w, p, 0, 1, "no spherical shoulder")
    _perp(w, 1, 2)
    off = _off_line(S, p[2], w[2])
    if off > DIST_TOL_MM:
        raise IKFamilyMismatch(FAMILY, "axes 1, 2 and 3 do not meet in one point (no spherical shoulder): axis 3 "
                                       "passes that far (mm) from where axes 1 and 2 meet", off)
    W = _meet(w, p, 4, 5, "no wrist point")
    _perp(w, 4, 5)
    for point, name in ((S, "shoulder"), (W, "wrist point")):
        off = _off_line(point, p[3], w[3])
        if off < ELBOW_CLEAR_MM:
            raise IKFamilyMismatch(FAMILY, f"axis 4 passes through the {name} (the elbow would not change the "
                                           f"shoulder-wrist distance)", off)
    return S, W


def _clean_R(R: np.ndarray) -> np.ndarray:
    """A rotation whose entries are all within 1e-12 of -1, 0 or 1 set to exactly those (a signed permutation)."""
    r = np.rint(R)
    return r + 0.0 if np.all(np.abs(R - r) < 1e-12) else R


def _clean_axes(w: np.ndarray) -> np.ndarray:
    """Unit axes (rows) with round-off components under 1e-12 set to 0 (axis-aligned axes cost no products)."""
    out = np.where(np.abs(w) < 1e-12, 0.0, w)
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def _clean_T(T: np.ndarray) -> np.ndarray:
    out = T.copy()
    out[:3, :3] = _clean_R(T[:3, :3])
    out[:3, 3] = [clean_mm(float(v)) for v in T[:3, 3]]
    return out


def derive_panda(ax: JointAxes) -> PandaParams:
    """The Panda-type description of an arm from its axes (module docstring), or :class:`IKFamilyMismatch`."""
    S, W = _check_structure(ax)
    w, p = ax.directions, ax.points_mm
    # model base: origin S, z along axis 1, y along axis 2
    z, y = w[0], w[1]
    B = _clean_T(make_T(np.column_stack([np.cross(y, z), y, z]), S))
    RB, tB = B[:3, :3], B[:3, 3]
    wB = w @ RB
    foot3, foot4 = line_closest_points(p[2], w[2], p[3], w[3])          # common normal of axes 3 and 4
    foot45, _ = line_closest_points(p[4], w[4], p[3], w[3])             # ... of axes 4 and 5, on axis 5
    # end frame: z along axis 7, origin on axis 7 nearest the flange, x the flange's x made square to it
    M = ax.flange_T
    o7 = p[6] + float((M[:3, 3] - p[6]) @ w[6]) * w[6]
    xe = M[:3, 0] - float(M[:3, 0] @ w[6]) * w[6]
    if np.linalg.norm(xe) < 1e-6:
        xe = M[:3, 1] - float(M[:3, 1] @ w[6]) * w[6]
    xe /= np.linalg.norm(xe)
    E = make_T(np.column_stack([xe, np.cross(w[6], xe), w[6]]), o7)
    F = _clean_T(np.linalg.inv(E) @ M)
    foot6, foot7 = line_closest_points(p[5], w[5], p[6], w[6])          # common normal of axes 6 and 7
    points = np.array([S, S, S, foot4, W, W, o7])
    beta = float(np.arctan2(wB[2] @ np.array([1.0, 0.0, 0.0]), wB[2][2]))
    return PandaParams(
        directions=_clean_axes(wB), points_mm=np.vectorize(clean_mm)((points - tB) @ RB),
        end_T=np.linalg.inv(B) @ E, base_T=B, flange_T=F,
        shoulder_mm=clean_mm(float(S @ w[0])),
        upper_arm_mm=clean_mm(float((foot3 - S) @ w[2])),
        a4_mm=clean_mm(line_distance_mm(p[2], w[2], p[3], w[3])),
        a5_mm=clean_mm(line_distance_mm(p[3], w[3], p[4], w[4])),
        forearm_mm=clean_mm(float((W - foot45) @ w[4])),
        a7_mm=clean_mm(float(np.linalg.norm(foot7 - foot6))),
        flange_mm=clean_mm(float((M[:3, 3] - foot7) @ w[6])),
        offset2_rad=clean_rad(beta))
