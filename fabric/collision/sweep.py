"""Version 1's sampled collision sweep, kept to compare against: the certified check that replaced it is
:mod:`fabric.collision.certify` (this one can miss a contact between two samples, and models the part as
one box per layer).

The robot's collision geometry (from its URDF, via Pinocchio) is checked with
coal against boxes for the table and the plate; pairs that touch by design
(the base link on the table) are left out. The program is swept at joint
configurations taken along every move, keeping a configuration whenever any
joint has turned ``step_deg`` since the last one kept (and at every target of a
joint move), so a large print does not mean a million coal calls.

The part as it grows is one box per printed layer (the bounding box of that
layer's deposited beads, from the layer below to the layer's top). A layer
counts once it is complete: while the nozzle prints layer L it is checked
against layers 0..L-1, whose top is one layer height below the nozzle tip.
Boxes are screened against each link's world AABB in numpy, and only the
overlapping (link, layer) pairs go to coal for an exact test.
"""
from __future__ import annotations

from dataclasses import dataclass

import coal
import numpy as np
import pinocchio as pin

from fabric.motion.program import MOVEJ, MOVEL, Program
from fabric.robot.cell import Cell

__all__ = ["Hit", "SweepResult", "CollisionChecker"]

MM = 1e-3


@dataclass
class Hit:
    config: int
    row: int
    body_a: str
    body_b: str


@dataclass
class SweepResult:
    collision_free: bool
    checked_configs: int
    min_distance_mm: float
    first_hit: Hit | None
    rows: np.ndarray           # row of each checked configuration
    frac: np.ndarray           # fraction along that row's move


class CollisionChecker:
    """Checks configurations of ``cell.robot`` against the cell's fixed bodies and a growing part."""

    def __init__(self, cell: Cell, clearance_mm: float = 0.0) -> None:
        self.cell = cell
        robot = cell.robot
        self.model = robot.pin_model
        self.data = self.model.createData()
        gm = robot.collision_model.copy()
        self.n_robot = len(gm.geometryObjects)
        env = []
        # cell frames (fabric.robot.cell): the table's reference is the centre of its top face (the box hangs
        # below it), the plate's the centre of its bottom face; coal boxes are centred on their origin
        for name, size_mm, T, below in (("table", cell.table_size_mm, cell.table_T, True),
                                        ("plate", cell.plate_size_mm, cell.true_plate_T, False)):
            box = coal.Box(*(np.asarray(size_mm, float) * MM))
            pose = np.asarray(T, float) @ _center_offset(size_mm, below)
            obj = pin.GeometryObject(name, 0, 0, pin.SE3(pose[:3, :3], pose[:3, 3] * MM), box)
            env.append(gm.addGeometryObject(obj))
        self.env_names = ["table", "plate"]
        # pairs: every robot geometry against every fixed body, except those attached to the base
        # (parent joint 0) or touching by design
        for gi in range(self.n_robot):
            g = gm.geometryObjects[gi]
            for ei in env:
                if g.parentJoint == 0:
                    continue
                gm.addCollisionPair(pin.CollisionPair(gi, ei))
        self.gm = gm
        self.gd = pin.GeometryData(gm)
        for req in self.gd.collisionRequests:
            req.security_margin = clearance_mm * MM
        self._robot_geoms = [gm.geometryObjects[i] for i in range(self.n_robot)]

    # --- configurations -------------------------------------------------------------

    @staticmethod
    def sample(program: Program, q_start: np.ndarray | None,
               step_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Configurations along the program's moves: (q (M,nq), row (M,), fraction along row (M,))."""
        q = program.q_rad
        motion = np.flatnonzero(program.op <= MOVEL)
        if len(motion) == 0:
            return np.zeros((0, q.shape[1])), np.zeros(0, int), np.zeros(0)
        prev = np.vstack([q_start if q_start is not None else q[motion[0]], q[motion[:-1]]])
        dq = np.abs(q[motion] - prev).max(axis=1)
        step = np.radians(step_deg)
        # joint moves: interpolate each finely; linear moves: keep targets once joints turned `step`
        nsub = np.where(program.op[motion] == MOVEJ, np.maximum(1, np.ceil(dq / step)), 1).astype(int)
        keep = program.op[motion] == MOVEJ
        acc = np.cumsum(dq)
        bucket = np.floor(acc / step)
        keep |= np.concatenate([[True], bucket[1:] != bucket[:-1]])
        keep |= np.concatenate([program.layer[motion][1:] != program.layer[motion][:-1], [True]])
        keep[-1] = True
        idx = np.flatnonzero(keep)
        reps = nsub[idx]
        rows = np.repeat(motion[idx], reps)
        frac = np.concatenate([np.arange(1, n + 1) / n for n in reps])
        p0 = np.repeat(prev[idx], reps, axis=0)
        p1 = q[rows]
        return p0 + (p1 - p0) * frac[:, None], rows, frac

    # --- checks -----------------------------------------------------------------------

    def check_configs(self, qs: np.ndarray, rows: np.ndarray | None = None, layers: np.ndarray | None = None,
                      part_boxes: np.ndarray | None = None) -> tuple[Hit | None, float, int]:
        """First hit among ``qs`` (in order), the minimum clearance (mm) to the fixed bodies, and configs checked."""
        min_d = np.inf
        for i, q in enumerate(qs):
            pin.updateGeometryPlacements(self.model, self.data, self.gm, self.gd, q)
            if pin.computeCollisions(self.gm, self.gd, True):
                for k, res in enumerate(self.gd.collisionResults):
                    if res.isCollision():
                        pair = self.gm.collisionPairs[k]
                        return (Hit(i, int(rows[i]) if rows is not None else -1,
                                    self.gm.geometryObjects[pair.first].name,
                                    self.gm.geometryObjects[pair.second].name), min_d, i + 1)
            if part_boxes is not None and layers is not None and layers[i] > 0:
                hit = self._part_hit(part_boxes[: layers[i]])
                if hit is not None:
                    return Hit(i, int(rows[i]) if rows is not None else -1, hit, "part"), min_d, i + 1
            if i % 16 == 0:
                pin.computeDistances(self.gm, self.gd)
                d = min(r.min_distance for r in self.gd.distanceResults)
                min_d = min(min_d, d / MM)
        return None, min_d, len(qs)

    def _part_hit(self, boxes: np.ndarray) -> str | None:
        """Exact test of robot geometries against the layer boxes whose AABBs overlap theirs."""
        for gi, g in enumerate(self._robot_geoms):
            M = self.gd.oMg[gi]
            lo, hi = _world_aabb(g.geometry, M)
            over = np.all((boxes[:, 0] <= hi) & (boxes[:, 1] >= lo), axis=1)
            for b in np.flatnonzero(over):
                half = (boxes[b, 1] - boxes[b, 0]) / 2
                box = coal.Box(*(2 * half))
                tf_box = coal.Transform3s(np.eye(3), boxes[b, 0] + half)
                tf_g = coal.Transform3s(M.rotation, M.translation)
                req, res = coal.CollisionRequest(), coal.CollisionResult()
                if coal.collide(g.geometry, tf_g, box, tf_box, req, res):
                    return g.name
        return None


def layer_boxes(program: Program, base_from_plate: np.ndarray, nozzle_gap_mm: float = 0.05) -> np.ndarray:
    """One box per layer (robot base frame, metres): bbox of the layer's extruding moves."""
    sel = (program.op == MOVEL) & (program.flow_mm3_mm > 0) & (program.layer >= 0)
    nl = int(program.layer.max()) + 1 if len(program) else 0
    boxes = np.zeros((max(nl, 0), 2, 3))
    if nl == 0 or not sel.any():
        return boxes[:0]
    pts = program.xyz_mm[sel] @ base_from_plate[:3, :3].T + base_from_plate[:3, 3]
    lay = program.layer[sel]
    order = np.argsort(lay, kind="stable")
    pts, lay = pts[order], lay[order]
    starts = np.searchsorted(lay, np.arange(nl))
    ends = np.searchsorted(lay, np.arange(nl), side="right")
    prev_top = None
    for L in range(nl):
        if starts[L] == ends[L]:
            boxes[L] = boxes[L - 1] if L else 0.0
            continue
        p = pts[starts[L]:ends[L]]
        lo, hi = p.min(axis=0), p.max(axis=0)
        bottom = prev_top if prev_top is not None else lo[2] - 1.0
        boxes[L, 0] = [lo[0], lo[1], bottom]
        boxes[L, 1] = [hi[0], hi[1], hi[2] - nozzle_gap_mm]
        prev_top = hi[2]
    return boxes * MM


def _center_offset(size_mm, below: bool) -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = float(size_mm[2]) / 2 * (-1.0 if below else 1.0)
    return T


def _world_aabb(geometry, M: pin.SE3) -> tuple[np.ndarray, np.ndarray]:
    geometry.computeLocalAABB()
    lo, hi = geometry.aabb_local.min_, geometry.aabb_local.max_
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    w = corners @ M.rotation.T + M.translation
    return w.min(axis=0), w.max(axis=0)
