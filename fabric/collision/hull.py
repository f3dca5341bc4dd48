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
GROUP_RADIUS_MM = 6.0        # consecutive pieces share a cover when they fit this much wider than the tool
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


def hull_check(bodies: RobotBodies, segs: Segments, idx: np.ndarray,
               checks: list[tuple[ToolCylinder, coal.BroadPhaseCollisionManager]]) -> list[HullResult]:
    """Check the swept hulls of each tool along linear segments ``idx`` against its tree."""
    if len(idx) == 0:
        return [HullResult(float("inf"), [], 0) for _ in checks]
    robot = bodies.cell.robot
    dq = segs.dq_abs[idx]
    chord = np.max([bodies.chord_error_mm(dq, tool.body) for tool, _ in checks], axis=0)
    tcp0 = robot.fk(segs.q0[idx])
    tcp1 = robot.fk(segs.q1[idx])
    length = np.linalg.norm(tcp1[:, :3, 3] - tcp0[:, :3, 3], axis=1)
    n = np.maximum(np.ceil(np.sqrt(chord / CHORD_TARGET_MM)), np.ceil(length / PIECE_MAX_MM))
    n = np.maximum(n, 1).astype(np.int64)
    # the pieces: segment, fractions of it, TCP at both ends
    seg = np.repeat(np.arange(len(idx)), n)
    first = np.repeat(np.cumsum(n) - n, n)
    k = np.arange(len(seg)) - first
    f0, f1 = k / n[seg], (k + 1) / n[seg]
    qa = segs.q0[idx][seg] + (segs.q1[idx] - segs.q0[idx])[seg] * f0[:, None]
    qb = segs.q0[idx][seg] + (segs.q1[idx] - segs.q0[idx])[seg] * f1[:, None]
    Ta = _fk_reuse(robot, qa, f0 == 0, tcp0[seg])
    Tb = _fk_reuse(robot, qb, f1 == 1, tcp1[seg])
    glob = idx[seg]
    s0 = segs.s0[glob] + (segs.s1[glob] - segs.s0[glob]) * f0
    s1 = segs.s0[glob] + (segs.s1[glob] - segs.s0[glob]) * f1
    out = []
    for tool, tree in checks:
        error = bodies.chord_error_mm(dq, tool.body)[seg] / n[seg] ** 2    # scales with the travel squared
        groups, covers = _groups(Ta, Tb, tool, error)
        clearance, touching = _check_covers(covers, tree)
        pieces = [i for g in touching for i in range(groups[g], groups[g + 1])]
        out.append(HullResult(clearance, [(int(glob[i]), float(s0[i]), float(s1[i])) for i in pieces], len(seg)))
    return out


def _check_covers(covers: tuple[np.ndarray, ...], tree: coal.BroadPhaseCollisionManager) -> tuple[float, list[int]]:
    """(smallest distance of the covers that do not touch ``tree``, indices of those that do)."""
    centre, axis, radius, half, grow = covers
    objs = []
    mgr = coal.DynamicAABBTreeCollisionManager()
    rot = _rotations_to(axis)
    for i in range(len(centre)):
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
    return clearance, touching


def _groups(Ta: np.ndarray, Tb: np.ndarray, tool: ToolCylinder, error: np.ndarray,
            ) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """Runs of consecutive pieces under one cover where they fit in a cylinder ``GROUP_RADIUS_MM`` wider
    than the tool (aligned blocks of 16, else of 4, else one piece): (group edges (G+1,), covers (centre,
    axis, radius, half, grow))."""
    ends = np.concatenate([(Ta[:, :3, 3] + Ta[:, :3, 2] * tool.offset_mm)[:, None],
                           (Tb[:, :3, 3] + Tb[:, :3, 2] * tool.offset_mm)[:, None]], axis=1)   # (n, 2, 3)
    axes = np.concatenate([Ta[:, None, :3, 2], Tb[:, None, :3, 2]], axis=1)
    n = len(ends)
    taken = np.zeros(n, bool)
    starts, sizes, covers = [], [], []
    for size in (16, 4, 1):
        cand = np.arange(0, n - size + 1, size)
        sel = cand[:, None] + np.arange(size)[None, :]
        free = ~taken[sel].all(axis=1) if size == 1 else ~taken[sel].any(axis=1)
        cand, sel = cand[free], sel[free]
        if len(cand) == 0:
            continue
        cover = _cover(ends[sel].reshape(len(cand), 2 * size, 3), axes[sel].reshape(len(cand), 2 * size, 3),
                       error[sel].max(axis=1), tool)
        keep = cover[-1] <= GROUP_RADIUS_MM if size > 1 else np.ones(len(cand), bool)
        starts.append(cand[keep])
        sizes.append(np.full(int(keep.sum()), size))
        covers.append(tuple(c[keep] for c in cover[:-1]))
        taken[sel[keep].ravel()] = True
    begin, size = np.concatenate(starts), np.concatenate(sizes)
    order = np.argsort(begin)
    edges = np.concatenate([begin[order], [n]])
    assert np.array_equal(edges[1:], (begin + size)[order]), "the groups tile the pieces"
    return edges, tuple(np.concatenate([c[f] for c in covers])[order] for f in range(5))


def _cover(ends: np.ndarray, axes: np.ndarray, error: np.ndarray, tool: ToolCylinder) -> tuple[np.ndarray, ...]:
    """The cylinder containing the tool's swept volume over a run of pieces (see the module docstring):
    ``ends`` (G, P, 3) the tool's centre at each piece end, ``axes`` (G, P, 3) its axis there, ``error``
    (G,) the largest chord error. Returns (centre, axis, radius, half, grow, spread across the axis)."""
    axis = axes.sum(axis=1)
    axis /= np.linalg.norm(axis, axis=1)[:, None]
    turn = np.arccos(np.clip(np.einsum("gpk,gk->gp", axes, axis), -1.0, 1.0)).max(axis=1)
    along = np.einsum("gpk,gk->gp", ends, axis)
    lo, hi = along.min(axis=1), along.max(axis=1)
    across = ends - along[..., None] * axis[:, None, :]
    mid = (across.min(axis=1) + across.max(axis=1)) / 2.0
    mid -= np.sum(mid * axis, axis=1)[:, None] * axis                  # onto the plane across the axis
    spread = np.linalg.norm(across - mid[:, None, :], axis=2).max(axis=1)
    centre = mid + ((lo + hi) / 2.0)[:, None] * axis
    rho = float(np.hypot(tool.radius_mm, tool.half_mm))
    grow = error + rho * turn + GJK_EPS_MM
    return centre, axis, tool.radius_mm + spread, tool.half_mm + (hi - lo) / 2.0, grow, spread


def _fk_reuse(robot, q: np.ndarray, known: np.ndarray, T_known: np.ndarray) -> np.ndarray:
    """TCP poses at ``q``, reusing those already known (segment ends)."""
    T = T_known.copy()
    todo = ~known
    if todo.any():
        T[todo] = robot.fk(q[todo])
    return T


def _rotations_to(axis: np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) taking z to each unit ``axis`` (columns: x, y, axis)."""
    helper = np.where(np.abs(axis[:, 0:1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    x = np.cross(helper, axis)
    x /= np.linalg.norm(x, axis=1)[:, None]
    y = np.cross(axis, x)
    return np.stack([x, y, axis], axis=2)
