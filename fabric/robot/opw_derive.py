"""The seven OPW parameters, joint offsets and signs of an arm, read from its joint axes at zero.

OPW (Brandstoetter, Angerer, Hofbaur 2014, "An analytical solution of the
inverse kinematics problem of industrial serial manipulators with an
ortho-parallel basis and a spherical wrist") describes ABB, KUKA, Fanuc and
Staubli arms by seven lengths in a reference pose where the arm points straight
up: axis 1 is the base z axis; axis 2 is parallel to the base y axis, ``a1``
forward of axis 1 and ``c1`` up; axis 3 is ``c2`` above axis 2; the wrist
centre is ``c3`` along the forearm from axis 3 and ``a2`` across it (positive
forward in the reference pose), and ``b`` sideways (along y); the end frame is
``c4`` beyond the wrist centre along axis 6. The model turns ``theta_i`` about
``z, y, y, z, y, z`` of the moving frames (``R = Rz Ry(t2 + t3) Rz Ry Rz``),
and a URDF joint relates to it by ``theta_i = sign_i * q_i + offset_i``.

The conditions, checked in this order (the first that fails is the error):
six revolute joints; axis 1 perpendicular to axis 2; axes 2 and 3 parallel and
apart; axis 4 perpendicular to them (were it parallel, the arm would have three
parallel axes: UR-type); axes 4, 5, 6 meeting in one point (the wrist centre)
with axis 5 perpendicular to axes 4 and 6. Then the parameters are read off
the lines (module ``joint_axes``), in a frame ``base_T`` with z along axis 1
(the URDF base when axis 1 is its z axis), the sign choices being: the arm
plane's x axis points from axis 1 towards the wrist centre at zero, the forearm
direction from axis 3 towards the wrist centre (``c3 > 0``), and the wrist
offsets ``offset_4``, ``offset_5`` within +-90 deg. ``offset_6`` is 0 and
``flange_T`` carries whatever rotation and offset the URDF flange has relative
to the OPW end frame. The caller verifies the result against Pinocchio.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabric.robot.arm_family import ANG_TOL, DIST_TOL_MM, IKFamilyMismatch
from fabric.robot.frames import make_T, rot_y, rot_z
from fabric.robot.joint_axes import JointAxes, line_closest_points, line_distance_mm

__all__ = ["OPWParams", "derive_opw", "six_revolute", "axis_base_T", "clean_mm", "clean_rad"]


@dataclass(frozen=True)
class OPWParams:
    """OPW lengths (mm), ``theta = sign * q + offset`` per joint, and the frames that place the model."""

    a1_mm: float
    a2_mm: float
    b_mm: float
    c1_mm: float
    c2_mm: float
    c3_mm: float
    c4_mm: float
    offsets_rad: tuple[float, ...]
    signs: tuple[float, ...]
    base_T: np.ndarray         # OPW base frame in the URDF base frame
    flange_T: np.ndarray       # OPW end frame -> URDF flange

    def lengths_mm(self) -> dict[str, float]:
        """The seven parameters by their names in the OPW paper."""
        return {"a1": self.a1_mm, "a2": self.a2_mm, "b": self.b_mm, "c1": self.c1_mm,
                "c2": self.c2_mm, "c3": self.c3_mm, "c4": self.c4_mm}


def six_revolute(ax: JointAxes, family: str) -> None:
    """Refuse anything but six revolute joints."""
    if len(ax.kinds) != 6:
        raise IKFamilyMismatch(family, f"needs 6 joints, the URDF has {len(ax.kinds)}")
    if not ax.revolute.all():
        j = int(np.argmin(ax.revolute))
        raise IKFamilyMismatch(family, f"joint {j + 1} is not revolute ({ax.kinds[j]})")


def axis_base_T(ax: JointAxes) -> np.ndarray:
    """A frame with z along axis 1 (pointing up the URDF base z), origin on axis 1, x along the base x."""
    z = ax.directions[0] * (1.0 if ax.directions[0][2] >= 0.0 else -1.0)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    if np.linalg.norm(x) < 1e-6:
        x = np.array([0.0, 1.0, 0.0]) - z[1] * z
    x /= np.linalg.norm(x)
    return make_T(np.column_stack([x, np.cross(z, x), z]), ax.points_mm[0])


def _sign(v: float) -> float:
    return -1.0 if v < 0.0 else 1.0


def _wrap(a: float) -> float:
    return float(a - 2.0 * np.pi * np.rint(a / (2.0 * np.pi)))


def clean_mm(x: float) -> float:
    """A length with round-off below 1e-9 mm set to exactly 0 (a zero offset then costs nothing)."""
    return 0.0 if abs(x) < 1e-9 else float(x)


def clean_rad(a: float) -> float:
    """An angle within 1e-12 rad of a multiple of 90 deg set to exactly that multiple."""
    k = float(np.rint(a / (np.pi / 2)))
    return k * (np.pi / 2) + 0.0 if abs(a - k * np.pi / 2) < 1e-12 else float(a)


def _check_structure(w: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The OPW conditions on the axes (base frame); returns the wrist centre."""
    if abs(w[0] @ w[1]) > ANG_TOL:
        raise IKFamilyMismatch("opw", "axis 1 is not perpendicular to axis 2", abs(float(w[0] @ w[1])))
    if np.linalg.norm(np.cross(w[1], w[2])) > ANG_TOL:
        raise IKFamilyMismatch("opw", "axes 2 and 3 are not parallel", float(np.linalg.norm(np.cross(w[1], w[2]))))
    if line_distance_mm(p[1], w[1], p[2], w[2]) < DIST_TOL_MM:
        raise IKFamilyMismatch("opw", "axes 2 and 3 coincide (no upper arm)")
    if np.linalg.norm(np.cross(w[2], w[3])) < ANG_TOL:
        raise IKFamilyMismatch("opw", "axis 4 is parallel to axes 2 and 3 (three parallel axes and an offset "
                                      "wrist: a UR-type arm, not a spherical wrist)")
    if abs(w[2] @ w[3]) > ANG_TOL:
        raise IKFamilyMismatch("opw", "axis 4 is not perpendicular to axes 2 and 3", abs(float(w[2] @ w[3])))
    a, b = line_closest_points(p[3], w[3], p[4], w[4])
    centre = 0.5 * (a + b)
    for j in (3, 4, 5):
        off = np.cross(centre - p[j], w[j])
        if np.linalg.norm(off) > DIST_TOL_MM:
            raise IKFamilyMismatch("opw", f"axes 4, 5 and 6 do not meet in one point (no spherical wrist): "
                                          f"axis {j + 1} passes that far (mm) from the wrist centre",
                                   float(np.linalg.norm(off)))
    for i, j in ((3, 4), (4, 5)):
        if abs(w[i] @ w[j]) > ANG_TOL:
            raise IKFamilyMismatch("opw", f"axis {j + 1} is not perpendicular to axis {i + 1}", abs(float(w[i] @ w[j])))
    return centre


def derive_opw(ax: JointAxes) -> OPWParams:
    """The OPW description of an arm from its axes (module docstring), or :class:`IKFamilyMismatch`."""
    six_revolute(ax, "opw")
    _check_structure(ax.directions, ax.points_mm)
    B = axis_base_T(ax)
    RB, tB = B[:3, :3], B[:3, 3]
    w = ax.directions @ RB                                  # axes and points in the OPW base frame
    p = (ax.points_mm - tB) @ RB
    M = np.linalg.inv(B) @ ax.flange_T
    centre = _check_structure(w, p)
    ez = np.array([0.0, 0.0, 1.0])
    s1 = _sign(w[0][2])
    # the arm plane at zero: x from axis 1 towards the wrist centre, y along axis 2
    xdir = np.cross(w[1], ez)
    xdir /= np.linalg.norm(xdir)
    ref = centre @ xdir if abs(centre @ xdir) > DIST_TOL_MM else p[1] @ xdir
    xdir *= _sign(float(ref))
    ydir = np.cross(ez, xdir)
    o1 = float(np.arctan2(xdir[1], xdir[0]))
    s2, s3 = _sign(w[1] @ ydir), _sign(w[2] @ ydir)
    a1, c1 = float(p[1] @ xdir), float(p[1][2])
    d23 = p[2] - p[1]
    dx, dz = float(d23 @ xdir), float(d23[2])
    c2, o2 = float(np.hypot(dx, dz)), float(np.arctan2(dx, dz))
    # forearm: from axis 3 towards the wrist centre
    dw = centre - p[2]
    u = w[3] * _sign(float(dw @ w[3]))
    t23 = float(np.arctan2(u @ xdir, u[2]))
    s4 = _sign(float(w[3] @ u))
    across = np.array([np.cos(t23) * xdir[0], np.cos(t23) * xdir[1], -np.sin(t23)])
    c3, a2 = float(dw @ u), float(dw @ across)
    b = float(centre @ ydir)
    # wrist offsets: axis 5 = Rc Rz(o4) e_y, axis 6 = Rc Rz(o4) Ry(o5) e_z
    Rc = rot_z(o1) @ rot_y(t23)
    v5 = Rc.T @ w[4]
    o4, s5 = float(np.arctan2(-v5[0], v5[1])), 1.0
    if abs(o4) > np.pi / 2 + 1e-9:
        o4, s5 = _wrap(o4 + np.pi), -1.0
    v6 = (Rc @ rot_z(o4)).T @ w[5]
    o5, s6 = float(np.arctan2(v6[0], v6[2])), 1.0
    if abs(o5) > np.pi / 2 + 1e-9:
        o5, s6 = _wrap(o5 + np.pi), -1.0
    Re = Rc @ rot_z(o4) @ rot_y(o5)
    c4 = float((M[:3, 3] - centre) @ Re[:, 2])
    E = make_T(Re, centre + c4 * Re[:, 2])
    return OPWParams(a1_mm=clean_mm(a1), a2_mm=clean_mm(a2), b_mm=clean_mm(b), c1_mm=clean_mm(c1),
                     c2_mm=c2, c3_mm=c3, c4_mm=clean_mm(c4),
                     offsets_rad=tuple(clean_rad(o) for o in (o1, o2, _wrap(t23 - o2), o4, o5, 0.0)),
                     signs=(s1, s2, s3, s4, s5, s6), base_T=B, flange_T=np.linalg.inv(E) @ M)
