"""The robot's collision bodies for the certified sweep: geometry, placements and motion bounds.

Bodies are the robot's collision geometries (Pinocchio, from the URDF with the
extruder tool: every link, ``tool_body``, ``tool_nozzle``) plus ``tool_tip``,
the exemption zone: a cylinder of the nozzle's radius from the nozzle tip up
``nozzle_clearance_mm`` (where ``tool_nozzle`` begins). The tip is the only
body allowed to touch the part, and only the beads of the layer the nozzle is
laying and of the layer just under it (see :mod:`fabric.collision.certify`).
The fixed bodies are the table and the plate (boxes, robot base frame); bodies
on the base (joint 0) are left out against them, as they stand on the table.
Self pairs are the robot's own (every pair except the same or neighbouring
joints) and the tip against the same links as the nozzle.

Motion bounds (all lengths mm, joint travel rad). For a joint path on which
every joint moves monotonically from ``q_a`` to ``q_b`` (a linear move's
joint interpolation; a rest-to-rest Ruckig joint move, see
:mod:`fabric.collision.path`), a point ``p`` of a body moves at speed
``|sum_j dq_j z_j x (p - o_j)| <= sum_j |dq_j| dist(p, axis_j)``, so over the
whole path it moves at most::

    M_b = sum_j |dq_j| * A_jb

with ``A_jb`` an upper bound of the distance of the body's points from joint
``j``'s axis, computed once per body from the corners of its bounding box:
for the body's own joint, their largest distance from that axis (exact in the
joint's frame; zero for a cylinder or sphere on the axis, which turning about
it leaves in place); for each joint before it, the part of the next joint's
offset across ``j``'s axis (fixed in ``j``'s frame) plus the largest distance
from that next joint's origin (the triangle inequality, valid in every
configuration). Joints after the body's own do not move it.

For a linear joint interpolation a second bound gives how far any point strays
from the straight chord between its two end positions (used by the swept hulls
of :mod:`fabric.collision.hull`): with ``S_j`` the travel of the joints before
``j``, ``|p''| <= sum_j |dq_j| (2 S_j D_jb + sum_{k>=j} |dq_k| D_kb)`` and the
chord error of a C2 curve over [0, 1] is at most ``max |p''| / 8``.
"""
from __future__ import annotations

from dataclasses import dataclass

import coal
import numpy as np
import pinocchio as pin

from fabric.robot.cell import Cell

__all__ = ["RobotBodies", "Body", "TIP", "NOZZLE", "MM", "GJK_EPS_MM", "display_name"]

MM = 1e-3                 # metres per mm: Pinocchio and coal work in metres, the API in mm
GJK_EPS_MM = 1e-3         # coal's distances are within 1 um (its GJK tolerance): every bound gives that away
TIP, NOZZLE = "tool_tip", "tool_nozzle"


def display_name(geometry_name: str) -> str:
    """``link_2_0`` (Pinocchio's name for a link's first geometry) -> ``link_2``."""
    base, sep, tail = geometry_name.rpartition("_")
    return base if sep and tail.isdigit() else geometry_name


@dataclass
class Body:
    """One collision body: its geometry, where it hangs (joint, placement) and its bounds."""

    name: str
    index: int                   # in the geometry model
    joint: int                   # parent joint (0: the base)
    geometry: object             # coal shape (metres)
    rate_mm: np.ndarray          # (nq,) A_jb: motion per rad of each joint
    reach_mm: np.ndarray         # (nq,) D_jb: distance bound from each joint's origin (0 off the chain)
    placement: np.ndarray        # (4, 4) in its joint's frame (mm)
    corners: np.ndarray          # (8, 3) corners of its local bounding box, in its own frame (mm)


class RobotBodies:
    """The robot's bodies of one cell, their placements at a configuration and their motion bounds.

    Not thread-safe (one Pinocchio data); the collision service serialises its checks.
    """

    def __init__(self, cell: Cell) -> None:
        self.cell = cell
        robot = cell.robot
        self.model = robot.pin_model
        self.data = self.model.createData()
        self.nq = int(self.model.nq)
        gm = robot.collision_model.copy()
        tool = robot.tool
        self.tip_radius_mm = tool.tip_mm / 2.0
        self.tip_length_mm = tool.nozzle_clearance_mm
        tcp = self.model.frames[robot.tcp_frame_id]
        tip_local = tcp.placement * pin.SE3(np.eye(3), np.array([0.0, 0.0, -self.tip_length_mm / 2.0]) * MM)
        tip_geom = coal.Cylinder(self.tip_radius_mm * MM, self.tip_length_mm * MM)
        tip = pin.GeometryObject(TIP + "_0", int(tcp.parentJoint), robot.tcp_frame_id, tip_local, tip_geom)
        tip_index = gm.addGeometryObject(tip)
        self.gm = gm
        self.gd = pin.GeometryData(gm)
        self.bodies: list[Body] = []
        for i, g in enumerate(gm.geometryObjects):
            rate, reach = self._bounds(g)
            place = g.placement.homogeneous.copy()
            place[:3, 3] /= MM
            self.bodies.append(Body(display_name(g.name), i, int(g.parentJoint), g.geometry, rate, reach, place,
                                    _corners(g.geometry)))
        self._axes = [_joint_axis(self.model, j) if j else np.zeros(3) for j in range(self.model.njoints)]
        self._joint_T = [_mm(self.model.jointPlacements[j].homogeneous) for j in range(self.model.njoints)]
        self.by_name = {b.name: b for b in self.bodies}
        self._spheres = {b.name: _sphere_cover(b.corners) for b in self.bodies}
        self._sphere = {b.name: ((b.corners.min(axis=0) + b.corners.max(axis=0)) / 2.0,
                                 float(np.linalg.norm(b.corners.max(axis=0) - b.corners.min(axis=0)) / 2.0))
                        for b in self.bodies}
        self.tcp_joint = int(tcp.parentJoint)
        self._tcp_placement = _mm(tcp.placement.homogeneous)
        self.moving = [b for b in self.bodies if b.joint > 0]
        # self pairs: the robot's own, plus the tip against whatever the nozzle is paired with
        nozzle = self.by_name[NOZZLE].index
        pairs = [(p.first, p.second) for p in robot.collision_model.collisionPairs]
        pairs += [(tip_index if a == nozzle else a, tip_index if b == nozzle else b) for a, b in pairs
                  if nozzle in (a, b)]
        self.self_pairs = [(self.bodies[a], self.bodies[b]) for a, b in pairs]
        self.env = _fixed_bodies(cell)
        self.objects = {b.name: coal.CollisionObject(b.geometry, coal.Transform3s()) for b in self.bodies}

    def axial_cylinders(self) -> list[tuple[Body, float, float, float]]:
        """Bodies that are cylinders on the TCP's z axis, rigid with it (the tip and the nozzle always, the
        tool body when the TCP lies on the flange's axis): (body, radius, half-length, centre offset along
        TCP z), mm. Turning about that axis leaves them where they are."""
        out = []
        inv = np.linalg.inv(self._tcp_placement)
        for b in self.bodies:
            if b.joint != self.tcp_joint or not isinstance(b.geometry, coal.Cylinder):
                continue
            rel = inv @ b.placement
            if abs(abs(rel[2, 2]) - 1.0) < 1e-9 and np.hypot(rel[0, 3], rel[1, 3]) < 1e-6:
                g = b.geometry
                out.append((b, float(g.radius) / MM, float(g.halfLength) / MM, float(rel[2, 3])))
        return out

    def sphere(self, poses: np.ndarray, body: Body) -> tuple[np.ndarray, float]:
        """The sphere around the body's bounding box, at ``poses`` (N, 4, 4): centres (N, 3), radius (mm)."""
        c, r = self._sphere[body.name]
        return poses[:, :3, :3] @ c + poses[:, :3, 3], r

    def spheres(self, poses: np.ndarray, body: Body) -> tuple[np.ndarray, float]:
        """A few equal spheres covering the body's bounding box, at ``poses`` (N, 4, 4): centres (N, k, 3)
        and their radius (mm)."""
        c, r = self._spheres[body.name]
        return np.swapaxes(poses[:, :3, :3] @ c.T, 1, 2) + poses[:, None, :3, 3], r

    # --- bounds ------------------------------------------------------------------------

    def _bounds(self, g: pin.GeometryObject) -> tuple[np.ndarray, np.ndarray]:
        """(A_jb, D_jb) for geometry ``g`` (see the module docstring), from the corners of its local
        bounding box: exact distances in its own joint's frame, then up the chain one joint offset at a time
        (the offset of a joint in its parent's frame turns about the parent's axis, so its component across
        that axis is fixed)."""
        geom = g.geometry
        geom.computeLocalAABB()
        lo, hi = np.asarray(geom.aabb_local.min_), np.asarray(geom.aabb_local.max_)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        pts = (corners @ g.placement.rotation.T + g.placement.translation) / MM      # in its joint's frame
        rate, reach = np.zeros(self.nq), np.zeros(self.nq)
        j = int(g.parentJoint)
        if j == 0:
            return rate, reach
        m = self.model
        axis = _joint_axis(m, j)
        rate[m.joints[j].idx_q] = float(np.max(np.linalg.norm(pts - np.outer(pts @ axis, axis), axis=1)))
        if _round_about(geom, g.placement, axis):     # turning about its own axis leaves it where it is
            rate[m.joints[j].idx_q] = 0.0
        lever = float(np.max(np.linalg.norm(pts, axis=1)))        # from this joint's origin
        reach[m.joints[j].idx_q] = lever
        child = j
        while m.parents[child] > 0:
            parent = int(m.parents[child])
            t = np.asarray(m.jointPlacements[child].translation, dtype=float) / MM
            a = _joint_axis(m, parent)
            rate[m.joints[parent].idx_q] = float(np.linalg.norm(t - a * float(t @ a))) + lever
            lever += float(np.linalg.norm(t))
            reach[m.joints[parent].idx_q] = lever
            child = parent
        return rate, reach

    def chain(self, body: Body) -> np.ndarray:
        """(nq,) bool: the joints that move ``body``."""
        out = np.zeros(self.nq, bool)
        j = body.joint
        while j > 0:
            out[self.model.joints[j].idx_q] = True
            j = int(self.model.parents[j])
        return out

    def pair_rate_mm(self, a: Body, b: Body) -> np.ndarray:
        """(nq,) motion per rad of each joint of ``b`` relative to ``a`` (and of ``a`` relative to ``b``):
        the joints that move both move them together and do not count."""
        ca, cb = self.chain(a), self.chain(b)
        return np.where(ca & ~cb, a.rate_mm, 0.0) + np.where(cb & ~ca, b.rate_mm, 0.0)

    def motion_mm(self, dq_abs: np.ndarray, body: Body) -> np.ndarray:
        """How far any point of ``body`` can move over joint travels ``dq_abs`` ((N, nq) -> (N,), mm)."""
        return np.asarray(dq_abs) @ body.rate_mm

    def chord_error_mm(self, dq_abs: np.ndarray, body: Body) -> np.ndarray:
        """How far any point of ``body`` can stray from its straight chord over a linear joint
        interpolation with travels ``dq_abs`` ((N, nq) -> (N,), mm; see the module docstring)."""
        d = np.atleast_2d(np.asarray(dq_abs, dtype=float))
        before = np.cumsum(d, axis=1) - d                                      # S_j
        after = np.cumsum((d * body.reach_mm)[:, ::-1], axis=1)[:, ::-1]       # sum_{k>=j} |dq_k| D_k
        return np.sum(d * (2.0 * before * body.reach_mm + after), axis=1) / 8.0

    def joint_frames(self, q: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """World rotation (N, 3, 3) and position (N, 3, mm) of every joint at joints ``q`` (N, nq): the
        chain product of the joints' placements and rotations, vectorised over configurations."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        m = self.model
        n = len(q)
        out = [(np.broadcast_to(np.eye(3), (n, 3, 3)), np.zeros((n, 3)))]
        for j in range(1, m.njoints):
            Rp, tp = out[int(m.parents[j])]
            P = self._joint_T[j]
            local = P[:3, :3] @ _rodrigues(self._axes[j], q[:, m.joints[j].idx_q])      # (N, 3, 3)
            out.append((Rp @ local, tp + Rp @ P[:3, 3]))
        return out

    def body_poses(self, frames: list[tuple[np.ndarray, np.ndarray]], body: Body) -> np.ndarray:
        """World poses (N, 4, 4), mm, of ``body`` from :meth:`joint_frames`."""
        R, t = frames[body.joint]
        out = np.empty((len(t), 4, 4))
        out[:, :3, :3] = R @ body.placement[:3, :3]
        out[:, :3, 3] = t + R @ body.placement[:3, 3]
        out[:, 3] = (0.0, 0.0, 0.0, 1.0)
        return out

    # --- placements --------------------------------------------------------------------

    def place(self, q: np.ndarray) -> None:
        """Put every body where it is at joints ``q`` (rad)."""
        pin.forwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        pin.updateGeometryPlacements(self.model, self.data, self.gm, self.gd)

    def transform(self, body: Body) -> coal.Transform3s:
        """The body's placement after :meth:`place` (metres)."""
        M = self.gd.oMg[body.index]
        return coal.Transform3s(M.rotation, M.translation)

    def placed_object(self, body: Body) -> coal.CollisionObject:
        """The body's collision object, moved to its placement after :meth:`place`."""
        obj = self.objects[body.name]
        obj.setTransform(self.transform(body))
        obj.computeAABB()
        return obj


def _round_about(geom, placement: pin.SE3, axis: np.ndarray) -> bool:
    """Whether ``geom`` (placed by ``placement`` in its joint's frame) is a solid of revolution about the
    joint's axis (a cylinder or capsule on it, a sphere centred on it)."""
    centre = np.asarray(placement.translation, dtype=float)
    on_axis = np.linalg.norm(centre - axis * float(centre @ axis)) < 1e-9
    if isinstance(geom, coal.Sphere):
        return bool(on_axis)
    if isinstance(geom, (coal.Cylinder, coal.Capsule)):
        return bool(on_axis and abs(abs(float(placement.rotation[:, 2] @ axis)) - 1.0) < 1e-9)
    return False


def _mm(T: np.ndarray) -> np.ndarray:
    out = np.array(T, dtype=float)
    out[:3, 3] /= MM
    return out


def _rodrigues(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) by ``angle`` (N,) about the unit ``axis``."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def _sphere_cover(corners: np.ndarray) -> tuple[np.ndarray, float]:
    """Centres (k, 3) and radius of k <= 4 spheres covering the box of ``corners``: the box cut into near
    cubes along its longest side, one sphere around each."""
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    ext = hi - lo
    axis = int(np.argmax(ext))
    other = max(float(np.delete(ext, axis).max()), 1e-9)
    k = int(np.clip(round(float(ext[axis]) / other), 1, 4))
    sub = ext.copy()
    sub[axis] /= k
    centres = np.repeat(((lo + hi) / 2.0)[None], k, axis=0)
    centres[:, axis] = lo[axis] + sub[axis] * (np.arange(k) + 0.5)
    return centres, float(np.linalg.norm(sub) / 2.0)


def _corners(geom) -> np.ndarray:
    geom.computeLocalAABB()
    lo, hi = np.asarray(geom.aabb_local.min_) / MM, np.asarray(geom.aabb_local.max_) / MM
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def _joint_axis(model: pin.Model, j: int) -> np.ndarray:
    """Unit rotation axis of revolute joint ``j`` in its own frame."""
    data = model.createData()
    q = pin.neutral(model)
    pin.computeJointJacobians(model, data, q)
    J = pin.getJointJacobian(model, data, j, pin.ReferenceFrame.LOCAL)
    col = J[3:, model.joints[j].idx_v]
    n = float(np.linalg.norm(col))
    return col / n if n > 0 else np.array([0.0, 0.0, 1.0])


def _fixed_bodies(cell: Cell) -> dict[str, coal.CollisionObject]:
    """Table and plate as coal boxes in the robot base frame (metres): the table's reference is the centre
    of its top face (the box hangs below it), the plate's the centre of its bottom face."""
    out = {}
    for name, size_mm, T, below in (("table", cell.table_size_mm, cell.table_T, True),
                                    ("plate", cell.plate_size_mm, cell.true_plate_T, False)):
        size = np.asarray(size_mm, dtype=float)
        pose = np.asarray(T, dtype=float).copy()
        pose[:3, 3] += pose[:3, 2] * (size[2] / 2.0) * (-1.0 if below else 1.0)
        obj = coal.CollisionObject(coal.Box(*(size * MM)), coal.Transform3s(pose[:3, :3], pose[:3, 3] * MM))
        obj.computeAABB()
        out[name] = obj
    return out
