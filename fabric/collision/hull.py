"""Swept hulls of the nozzle and its tip along linear moves, checked a whole layer at a time.

The nozzle and the tip are cylinders on the TCP's z axis. Along a linear
move every point ``p`` of a rigid body stays within the chord error ``e`` of
the straight chord between its two end positions
(:meth:`RobotBodies.chord_error_mm`), and a chord from ``p_a`` to ``p_b`` lies
in the convex hull of the body at both ends. So the whole swept volume lies
in ``hull(B_a, B_b)`` grown by ``e``. For two cylinders of radius ``r`` and
half-length ``h`` whose centres differ by ``v`` and axes by an angle ``t``,
that hull lies in the cylinder centred between them along their mean axis,
of radius ``r + |v_perp| / 2`` and half-length ``h + |v_par| / 2``, grown by
``rho * t / 2`` (``rho``: the cylinder's half-diagonal), which is how far
turning an end cylinder onto the mean axis moves it. The growth is coal's
swept-sphere radius, so the solid checked contains every position the body
takes between the two ends.

A linear move is cut into pieces until the chord error is at most
``CHORD_TARGET_MM`` and a piece at most ``PIECE_MAX_MM`` long; all pieces of
a layer go into one dynamic AABB tree, and a single coal call per tree
answers whether any of them touches the part, the plate or the table, and
another the smallest distance of those that do not: a certified lower bound
of the clearance along every linear move of the layer. The pieces that touch
are handed back for the exact refinement (:mod:`fabric.collision.certify`).
"""
from __future__ import annotations

from dataclasses import dataclass

import coal
import numpy as np

from fabric.collision.bodies import MM, Body, RobotBodies
from fabric.collision.path import Segments

__all__ = ["ToolCylinder", "HullResult", "hull_check", "CHORD_TARGET_MM", "PIECE_MAX_MM", "GJK_EPS_MM"]

CHORD_TARGET_MM = 0.02       # chord error allowed per piece
PIECE_MAX_MM = 10.0          # longest piece (the swept cylinder grows by half of it sideways)
GJK_EPS_MM = 1e-3            # coal's distances are within 1 um (GJK tolerance): bounds give that away


@dataclass(frozen=True)
class ToolCylinder:
    """A cylinder on the TCP's z axis: radius, half-length and centre offset along TCP z (mm)."""

    body: Body
    radius_mm: float
    half_mm: float
    offset_mm: float


@dataclass
class HullResult:
    clearance_mm: float          # min distance over the pieces that do not touch (inf: none)
    touching: list[tuple[int, float, float]]   # (segment, s0, s1) pieces that touch, in path order
    pieces: int


def hull_check(bodies: RobotBodies, segs: Segments, idx: np.ndarray, tool: ToolCylinder,
               tree: coal.BroadPhaseCollisionManager) -> HullResult:
    """Check the swept hulls of ``tool`` along linear segments ``idx`` against ``tree``."""
    if len(idx) == 0:
        return HullResult(float("inf"), [], 0)
    robot = bodies.cell.robot
    dq = segs.dq_abs[idx]
    chord = bodies.chord_error_mm(dq, tool.body)
    tcp0 = robot.fk(segs.q0[idx])
    tcp1 = robot.fk(segs.q1[idx])
    length = np.linalg.norm(tcp1[:, :3, 3] - tcp0[:, :3, 3], axis=1)
    n = np.maximum(np.ceil(np.sqrt(chord / CHORD_TARGET_MM)), np.ceil(length / PIECE_MAX_MM))
    n = np.maximum(n, 1).astype(np.int64)
    # the pieces: segment, fractions of it, joints at both ends
    seg = np.repeat(np.arange(len(idx)), n)
    first = np.repeat(np.cumsum(n) - n, n)
    k = np.arange(len(seg)) - first
    f0, f1 = k / n[seg], (k + 1) / n[seg]
    qa = segs.q0[idx][seg] + (segs.q1[idx] - segs.q0[idx])[seg] * f0[:, None]
    qb = segs.q0[idx][seg] + (segs.q1[idx] - segs.q0[idx])[seg] * f1[:, None]
    Ta = _fk_reuse(robot, qa, f0 == 0, tcp0[seg])
    Tb = _fk_reuse(robot, qb, f1 == 1, tcp1[seg])
    error = chord[seg] / n[seg] ** 2                      # chord error scales with the square of the travel
    centre, axis, radius, half, grow = _cover(Ta, Tb, tool, error)
    objs = []
    mgr = coal.DynamicAABBTreeCollisionManager()
    rot = _rotations_to(axis)
    for i in range(len(seg)):
        geom = coal.Cylinder(float(radius[i] * MM), float(2.0 * half[i] * MM))
        geom.setSweptSphereRadius(float(grow[i] * MM))
        obj = coal.CollisionObject(geom, rot[i], centre[i] * MM)
        obj.computeAABB()
        objs.append(obj)
        mgr.registerObject(obj)
    mgr.setup()
    hit = coal.CollisionCallBackDefault()
    tree.collide(mgr, hit)
    touching: list[int] = []
    if hit.data.result.isCollision():
        for i, obj in enumerate(objs):            # which: one query each, in path order
            one = coal.CollisionCallBackDefault()
            tree.collide(obj, one)
            if one.data.result.isCollision():
                touching.append(i)
                mgr.unregisterObject(obj)
    clearance = float("inf")
    if mgr.size():
        dist = coal.DistanceCallBackDefault()
        tree.distance(mgr, dist)
        clearance = float(dist.data.result.min_distance) / MM - GJK_EPS_MM
    glob = idx[seg]
    s0 = segs.s0[glob] + (segs.s1[glob] - segs.s0[glob]) * f0
    s1 = segs.s0[glob] + (segs.s1[glob] - segs.s0[glob]) * f1
    out = [(int(glob[i]), float(s0[i]), float(s1[i])) for i in touching]
    return HullResult(clearance, out, len(seg))


def _fk_reuse(robot, q: np.ndarray, known: np.ndarray, T_known: np.ndarray) -> np.ndarray:
    """TCP poses at ``q``, reusing those already known (segment ends)."""
    T = T_known.copy()
    todo = ~known
    if todo.any():
        T[todo] = robot.fk(q[todo])
    return T


def _cover(Ta: np.ndarray, Tb: np.ndarray, tool: ToolCylinder, error: np.ndarray) -> tuple[np.ndarray, ...]:
    """The growing cylinder containing the tool's swept volume between poses Ta and Tb (see module doc)."""
    aa, ab = Ta[:, :3, 2], Tb[:, :3, 2]
    ca = Ta[:, :3, 3] + aa * tool.offset_mm
    cb = Tb[:, :3, 3] + ab * tool.offset_mm
    mean = aa + ab
    axis = mean / np.linalg.norm(mean, axis=1)[:, None]
    v = cb - ca
    v_par = np.sum(v * axis, axis=1)
    v_perp = np.linalg.norm(v - v_par[:, None] * axis, axis=1)
    turn = np.arccos(np.clip(np.sum(aa * ab, axis=1), -1.0, 1.0))
    rho = float(np.hypot(tool.radius_mm, tool.half_mm))
    radius = tool.radius_mm + v_perp / 2.0
    half = tool.half_mm + np.abs(v_par) / 2.0
    grow = error + rho * turn / 2.0 + GJK_EPS_MM
    return (ca + cb) / 2.0, axis, radius, half, grow


def _rotations_to(axis: np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) taking z to each unit ``axis`` (columns: x, y, axis)."""
    helper = np.where(np.abs(axis[:, 0:1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    x = np.cross(helper, axis)
    x /= np.linalg.norm(x, axis=1)[:, None]
    y = np.cross(axis, x)
    return np.stack([x, y, axis], axis=2)
