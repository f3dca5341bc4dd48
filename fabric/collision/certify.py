"""Certified collision sweep: every motion, every body, against the part as printed, the plate, the table
and the robot itself, with nothing missed between checked configurations.

What is checked. Every robot link, the tool body, the nozzle and its tip
(:mod:`fabric.collision.bodies`) along the whole path (:mod:`fabric.collision.path`:
linear moves, joint moves, the approach, travels, the lift and the return
home; or one live joint move of the station) against the table, the plate,
every bead laid before the motion (:mod:`fabric.collision.beads`) and, for
the robot itself, every pair of its bodies that are not neighbours (the tool
against its own arm).

The one exemption. The nozzle's tip (``tool_tip``: the nozzle's radius, from
the tip ``nozzle_clearance_mm`` up, 4 mm x 1 mm on the paper's extruder) lays
the bead under it and rests on the layer below: against the beads of the
layer it is laying and of the layer under it, and only those, it is not
checked. The rest of the nozzle begins where the tip ends, so it clears the
bead being laid by ``nozzle_clearance_mm``, and is checked against
everything. Against the plate, the table and every other bead the tip is
checked too: printing the first layer it is one layer height above the plate,
which is what the certified clearance of a normal print comes down to.

How nothing is missed (conservative advancement). A piece of the path is
certified for a body when the body's distance lower bound ``d`` at the start
of the piece exceeds the bound ``M`` on how far any of its points can move
over the piece (:meth:`RobotBodies.motion_mm`; for two robot bodies the sum
of theirs): the body cannot reach anything it was not already closer to.
Walking along the path, one distance query certifies every following piece
up to a total motion of ``d``, so bodies far from everything take few queries.
A single segment that cannot be certified so is bisected (at the exact
midpoint of the twin's path), each end taking an exact distance, and is
certified once ``(d_a + d_b - M) / 2`` is above the tolerance (that is its
clearance lower bound); a sample at the tolerance or closer, or a piece still
uncertified once its motion is below the tolerance, is a hit. The nozzle and
the tip along linear moves are instead checked as swept hulls, a layer at a
time (:mod:`fabric.collision.hull`): they slide a layer height or a millimetre
above flat layers, where distance-and-motion alone would take a query per
millimetre. The certified clearance of a sweep is the smallest of all these
lower bounds.

Broad phase. The beads are boxes in coal's dynamic AABB trees, in print
order: the path is cut where the tip's layer changes, and before each such
stretch the beads laid up to its last row go into the trees (one of them
without the tip's two exempt layers). A bead laid during the stretch is in
the tree for the whole stretch, which can only make distances smaller; when
that matters (a distance too small to go on), the refinement asks again with
exactly the beads laid before the row, found by their bounding boxes.
"""
from __future__ import annotations

import heapq
import time
from dataclasses import dataclass, field

import coal
import numpy as np

from fabric.collision.beads import BeadSolids
from fabric.collision.bodies import MM, NOZZLE, TIP, Body, RobotBodies
from fabric.collision.hull import GJK_EPS_MM, ToolCylinder, hull_check
from fabric.collision.path import LIVE_ROW, Segments, move_segments, program_segments
from fabric.motion.program import Program
from fabric.robot.cell import Cell

__all__ = ["Certifier", "SweepHit", "SweepResult", "TOLERANCE_MM", "exemption_text"]

TOLERANCE_MM = 0.01          # two bodies this close count as touching
_MAX_DEPTH = 60              # bisections of one segment (a joint move's piece is 0.05 rad: far below 1 um)
EXACT_MARGIN_MM = 2.0        # an exact query looks this far around a body for beads


def exemption_text(bodies: RobotBodies) -> str:
    """The exemption zone in words, for reports and docs."""
    return (f"{TIP}: r {bodies.tip_radius_mm:g} mm x {bodies.tip_length_mm:g} mm at the nozzle tip, "
            f"exempt against the layer being laid and the one under it")


@dataclass
class SweepHit:
    """Where a sweep first finds two bodies touching."""

    segment: int
    row: int
    s: float                     # fraction along the row's move (time fraction for a joint move)
    body: str
    other: str                   # table, plate, part or a robot body
    distance_mm: float
    q_rad: np.ndarray
    bead: int = -1               # index into the bead solids when ``other`` is the part


@dataclass
class SweepResult:
    collision_free: bool
    clearance_mm: float          # certified lower bound of the clearance (inf: nothing moved)
    clearance_body: str
    configs: int                 # configurations at which distances were computed
    pieces: int                  # swept hull pieces
    segments: int                # path segments
    beads: int
    first_hit: SweepHit | None
    elapsed_s: float
    segs: Segments | None = field(default=None, repr=False)


@dataclass
class _Probe:
    d: float
    other: str = ""
    bead: int = -1
    exact: bool = False          # with exactly the beads laid before the row (else the stretch's superset)


@dataclass
class _Item:
    """Something walked along the path: a body against the part and the fixed bodies, or two robot bodies."""

    name: str
    body: Body
    other: Body | None           # a self pair's second body
    tree: coal.BroadPhaseCollisionManager | None
    rate_mm: np.ndarray          # (nq,) motion per rad of each joint (both bodies' for a pair)
    tip: bool = False


class PartTrees:
    """The broad phase: the beads laid so far with the table and the plate (``all``), and the same without
    the tip's two exempt layers (``tip``). Beads go in (and out of ``tip``) as the sweep advances."""

    def __init__(self, beads: BeadSolids, env: dict[str, coal.CollisionObject]) -> None:
        self.beads = beads
        self.all = coal.DynamicAABBTreeCollisionManager()
        self.tip = coal.DynamicAABBTreeCollisionManager()
        self.coarse = coal.DynamicAABBTreeCollisionManager()
        for obj in env.values():
            for tree in (self.all, self.tip, self.coarse):
                tree.registerObject(obj)
        for tree in (self.all, self.tip, self.coarse):
            tree.setup()
        self.count = 0                                   # beads 0..count-1 are in ``all``
        self.pending: list[int] = []                     # in ``all``, not in ``tip`` (exempt when added)
        self.tip_layers: dict[int, list[int]] = {}       # layer -> beads in ``tip``
        self.exempt: tuple[int, ...] = ()
        # the coarse tree: one box per layer around all of that layer's beads, in once its first bead is
        layers, first = np.unique(beads.layer, return_index=True)
        order = np.argsort(first)
        self._layer_first = first[order]
        self._layer_boxes = [_layer_box(beads, beads.layer == layer) for layer in layers[order]]
        self._layers_in = 0

    def advance(self, count: int, tip_layer: int) -> None:
        """Hold beads 0..count-1; ``tip`` leaves out layers ``tip_layer`` and ``tip_layer - 1``."""
        beads = self.beads
        if count > self.count:
            new = np.arange(self.count, count)
            for obj in beads.objects(new):
                self.all.registerObject(obj)
            self.pending.extend(new.tolist())
            self.count = count
        while self._layers_in < len(self._layer_first) and self._layer_first[self._layers_in] < self.count:
            self.coarse.registerObject(self._layer_boxes[self._layers_in])
            self._layers_in += 1
        exempt = (tip_layer, tip_layer - 1) if tip_layer >= 0 else ()
        for layer in exempt:                             # beads that become exempt leave ``tip``
            out = self.tip_layers.pop(layer, [])
            for obj in beads.objects(np.asarray(out, dtype=np.int64)):
                self.tip.unregisterObject(obj)
            self.pending.extend(out)
        keep, add = [], []
        layers = beads.layer
        for i in self.pending:
            (keep if int(layers[i]) in exempt else add).append(i)
        for i, obj in zip(add, beads.objects(np.asarray(add, dtype=np.int64)), strict=True):
            self.tip.registerObject(obj)
            self.tip_layers.setdefault(int(layers[i]), []).append(i)
        self.pending, self.exempt = keep, exempt


def _layer_box(beads: BeadSolids, sel: np.ndarray) -> coal.CollisionObject:
    """An axis-aligned box around the selected beads (a lower bound of the distance to any of them)."""
    lo, hi = beads.lo[sel].min(axis=0), beads.hi[sel].max(axis=0)
    obj = coal.CollisionObject(coal.Box(*((hi - lo) * MM)), np.eye(3), (lo + hi) / 2.0 * MM)
    obj.computeAABB()
    return obj


class Certifier:
    """Certified sweeps for one cell (see the module docstring). Not thread-safe."""

    def __init__(self, cell: Cell, tolerance_mm: float = TOLERANCE_MM) -> None:
        self.cell = cell
        self.bodies = RobotBodies(cell)
        self.tol = float(tolerance_mm)
        b = self.bodies
        tool = cell.robot.tool
        self.tools = (
            ToolCylinder(b.by_name[TIP], b.tip_radius_mm, b.tip_length_mm / 2.0, -b.tip_length_mm / 2.0),
            ToolCylinder(b.by_name[NOZZLE], tool.nozzle_diameter_mm / 2.0, tool.nozzle_length_mm / 2.0,
                         -(tool.nozzle_clearance_mm + tool.nozzle_length_mm / 2.0)),
        )
        self._req = coal.DistanceRequest()
        self._res = coal.DistanceResult()
        self._cb = coal.DistanceCallBackDefault()

    @property
    def exemption(self) -> str:
        return exemption_text(self.bodies)

    # --- entry points -----------------------------------------------------------------------

    def sweep_program(self, program: Program, q_start: np.ndarray | None = None,
                      beads: BeadSolids | None = None) -> SweepResult:
        """Certify ``program`` from ``q_start`` (default: the cell's home) against its own beads."""
        t0 = time.perf_counter()
        q0 = self.cell.home_q_rad if q_start is None else np.asarray(q_start, dtype=float)
        segs = program_segments(program, self.cell.robot, q0)
        solids = BeadSolids.from_program(program) if beads is None else beads
        return self._sweep(segs, solids, t0)

    def sweep_move(self, q_from: np.ndarray, q_to: np.ndarray, beads: BeadSolids | None = None,
                   tip_layer: int = -1, vel_r: float = 0.5, kind: str = "joint") -> SweepResult:
        """Certify one joint move (as the twin times it, at ``vel_r``) against ``beads`` (all laid before)."""
        t0 = time.perf_counter()
        segs = move_segments(self.cell.robot, q_from, q_to, vel_r, kind, tip_layer)
        return self._sweep(segs, beads if beads is not None else BeadSolids.empty(), t0)

    # --- the sweep ------------------------------------------------------------------------------

    def _sweep(self, segs: Segments, beads: BeadSolids, t0: float) -> SweepResult:
        self.segs, self.beads = segs, beads
        self.trees = PartTrees(beads, self.bodies.env)
        self.configs = self.pieces = 0
        self.clearance, self.clearance_body = float("inf"), ""
        self._placed: object = None
        hit: SweepHit | None = None
        for a, b in segs.runs(self._stretch_keys()):
            last_row = int(segs.row[b - 1])
            count = len(beads) if last_row >= LIVE_ROW else int(np.searchsorted(beads.row, last_row, "left"))
            self.trees.advance(count, int(segs.tip_layer[a]))
            self._epoch_motion(a, b)
            hits = self._hulls(a, b) + self._walk(a, b)
            if hits:
                hit = min(hits, key=lambda h: (h.segment, h.s))
                break
        return SweepResult(hit is None, self.clearance, self.clearance_body, self.configs, self.pieces, len(segs),
                           len(beads), hit, time.perf_counter() - t0, segs)

    def _stretch_keys(self) -> np.ndarray:
        """Per segment, what its stretch shares: the tip's layer, and whether that layer's first bead is laid
        yet (so the nozzle lifting off one layer is not held against the next layer's beads)."""
        segs, beads = self.segs, self.beads
        first_row = {}
        if len(beads):
            layers, first = np.unique(beads.layer, return_index=True)
            first_row = dict(zip(layers.tolist(), beads.row[first].tolist(), strict=True))
        started = np.array([r >= first_row.get(t, LIVE_ROW + 1) for r, t in
                            zip(segs.row.tolist(), segs.tip_layer.tolist(), strict=True)], dtype=bool)
        return segs.tip_layer * 2 + started

    def _bound(self, lb: float, name: str) -> None:
        if lb < self.clearance:
            self.clearance, self.clearance_body = lb, name

    # --- nozzle and tip along linear moves: swept hulls ---------------------------------------

    def _hulls(self, a: int, b: int) -> list[SweepHit]:
        segs = self.segs
        idx = a + np.flatnonzero(~segs.joint[a:b])
        hits: list[SweepHit] = []
        checks = [(tool, self.trees.tip if tool.body.name == TIP else self.trees.all) for tool in self.tools]
        for (tool, _), res in zip(checks, hull_check(self.bodies, segs, idx, checks), strict=True):
            self.pieces += res.pieces
            self._bound(res.clearance_mm, tool.body.name)
            item = self._body_item(tool.body)
            for k, s0, s1 in res.touching:
                qa, qb = segs.q_at(k, s0), segs.q_at(k, s1)
                pa, pb = self._probe(item, k, qa), self._probe(item, k, qb)
                h = self._refine(item, k, s0, qa, pa, s1, qb, pb, 0)
                if h is not None:
                    hits.append(h)
                    break
        return hits

    # --- every other body, and the tip and nozzle along joint moves: conservative advancement -----

    def _items(self) -> list[tuple[_Item, np.ndarray | None]]:
        """(item, segment mask or None for all) for every walk."""
        out: list[tuple[_Item, np.ndarray | None]] = []
        for body in self.bodies.moving:
            out.append((self._body_item(body), "joint" if body.name in (TIP, NOZZLE) else None))
        for x, y in self.bodies.self_pairs:
            out.append((_Item(f"{x.name} <-> {y.name}", x, y, None, self.bodies.pair_rate_mm(x, y)), None))
        return out

    def _epoch_motion(self, a: int, b: int) -> None:
        """Motion bounds of every moving body over segments [a, b): (J, C, E) per body (joint bound, chord
        part, chord error; see :meth:`RobotBodies.chord_parts_mm`), from one vectorised FK of the stretch."""
        segs, bodies = self.segs, self.bodies
        frames = bodies.joint_frames(np.vstack([segs.q0[a:b], segs.q1[b - 1:b]]))
        dq = segs.dq_abs[a:b]
        self._a = a
        self._parts = {}
        for body in bodies.bodies:
            if body.joint == 0:                                # on the base: does not move
                zero = np.zeros(b - a)
                self._parts[body.name] = (zero, zero, zero)
                continue
            C, E = bodies.chord_parts_mm(bodies.body_poses(frames, body), body, dq)
            self._parts[body.name] = (bodies.motion_mm(dq, body), C, E)

    def _item_parts(self, item: _Item) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        J, C, E = self._parts[item.body.name]
        if item.other is None:
            return J, C, E
        _, C2, E2 = self._parts[item.other.name]
        a = self._a
        return self.segs.dq_abs[a:a + len(J)] @ item.rate_mm, C + C2, E + E2

    def _motion(self, item: _Item) -> np.ndarray:
        """Per segment of the stretch: how far the item's body can move (a pair: relative to the other)."""
        J, C, E = self._item_parts(item)
        linear = ~self.segs.joint[self._a:self._a + len(J)]
        return np.where(linear, np.minimum(J, C + 2.0 * E), J)

    def _piece_motion(self, item: _Item, k: int, sa: float, sb: float, qa: np.ndarray, qb: np.ndarray) -> float:
        """The motion bound of the piece [sa, sb] of segment ``k``."""
        segs = self.segs
        joint = float(np.abs(qb - qa) @ item.rate_mm)
        if segs.joint[k]:
            return joint                                   # the joints move monotonically: travel = difference
        J, C, E = (float(v[k - self._a]) for v in self._item_parts(item))
        span = float(segs.s1[k] - segs.s0[k])
        f = (sb - sa) / span if span > 0 else 1.0
        return min(joint, f * C + 4.0 * E) if f < 1.0 else min(joint, C + 2.0 * E)

    def _body_item(self, body: Body) -> _Item:
        tip = body.name == TIP
        return _Item(body.name, body, None, self.trees.tip if tip else self.trees.all, body.rate_mm, tip)

    def _walk(self, a: int, b: int) -> list[SweepHit]:
        """Conservative advancement of every item over segments [a, b), one Pinocchio placement per vertex
        shared by the items due there."""
        segs = self.segs
        n = b - a
        dq = segs.dq_abs[a:b]
        joint = segs.joint[a:b]
        items = self._items()
        state = []
        heap: list[tuple[int, int]] = []
        for j, (item, which) in enumerate(items):
            mask = joint if isinstance(which, str) else np.ones(n, bool)
            runs = _runs(mask)
            cum = np.concatenate([[0.0], np.cumsum(self._motion(item))])
            state.append({"runs": runs, "run": 0, "cum": cum, "prev": None, "done": not runs})
            if runs:
                heap.append((runs[0][0], j))
        heapq.heapify(heap)
        hits: list[SweepHit] = []
        while heap:
            i, j = heapq.heappop(heap)
            st, item = state[j], items[j][0]
            r0, r1 = st["runs"][st["run"]]
            cum = st["cum"]
            if i >= r1:                                     # end of a run: close its last stretch, go on
                if st["prev"] is not None:
                    self._close(item, st, i, self._query(item, segs.q1[b - 1] if i >= n else segs.q0[a + i]))
                st["prev"] = None
                st["run"] += 1
                if st["run"] < len(st["runs"]):
                    heapq.heappush(heap, (st["runs"][st["run"]][0], j))
                continue
            k = a + i
            q = segs.q0[k]
            step = float(cum[i + 1] - cum[i])
            probe = self._probe(item, k, q, step + 2.0 * self.tol)
            if st["prev"] is not None:
                self._close(item, st, i, probe)
            if probe.d <= self.tol:
                hits.append(self._hit(item, k, float(segs.s0[k]), q, probe))
                continue                                    # this item stops at its first hit
            # an exact distance holds for this segment's row only: it may certify this segment, no further
            last = i + 1 if probe.exact else r1
            u = min(int(np.searchsorted(cum, cum[i] + probe.d - 2.0 * self.tol, "left")) - 1, last)
            if u > i:                                       # certified up to vertex u by this one distance
                st["prev"] = (i, probe.d)
                heapq.heappush(heap, (u, j))
                continue
            st["prev"] = None                               # segment i moves further than the clearance: bisect
            q1 = segs.q1[k]
            h = self._refine(item, k, float(segs.s0[k]), q, probe, float(segs.s1[k]), q1,
                             self._probe(item, k, q1, step + 2.0 * self.tol), 0, step)
            if h is not None:
                hits.append(h)
                continue
            heapq.heappush(heap, (i + 1, j))
        return hits

    def _close(self, item: _Item, st: dict, i: int, probe: _Probe) -> None:
        """The clearance lower bound of the stretch certified from the item's last query to vertex ``i``."""
        pi, pd = st["prev"]
        span = float(st["cum"][i] - st["cum"][pi])
        self._bound(max(pd - span, (pd + probe.d - span) / 2.0), item.name)

    def _refine(self, item: _Item, k: int, sa: float, qa: np.ndarray, pa: _Probe, sb: float, qb: np.ndarray,
                pb: _Probe, depth: int, motion: float | None = None) -> SweepHit | None:
        """Certify segment ``k`` between fractions ``sa`` and ``sb`` by bisection, or find where it touches.

        A piece is certified when its clearance lower bound ``(d_a + d_b - M) / 2`` is above the tolerance
        and at least half the smaller end distance (so that the reported clearance says something); it is
        a hit when an end is within the tolerance, or when its motion is below the tolerance and it still
        cannot be certified."""
        if pa.d <= self.tol:
            return self._hit(item, k, sa, qa, pa)
        if pb.d <= self.tol and motion is not None and motion <= self.tol:
            return self._hit(item, k, sb, qb, pb)
        if motion is None:
            motion = self._piece_motion(item, k, sa, sb, qa, qb)
        lb = (pa.d + pb.d - motion) / 2.0
        if lb > self.tol and (lb >= 0.5 * min(pa.d, pb.d) or motion <= self.tol):
            self._bound(lb, item.name)
            return None
        if motion <= self.tol or depth >= _MAX_DEPTH:
            s, q, p = (sa, qa, pa) if pa.d <= pb.d else (sb, qb, pb)
            return self._hit(item, k, s, q, p)
        sm = (sa + sb) / 2.0
        qm = self.segs.q_at(k, sm)
        pm = self._probe(item, k, qm, motion / 2.0 + 2.0 * self.tol)
        left = self._refine(item, k, sa, qa, pa, sm, qm, pm, depth + 1)
        if left is not None:
            return left
        return self._refine(item, k, sm, qm, pm, sb, qb, pb, depth + 1)

    # --- distances ------------------------------------------------------------------------------

    def _place(self, q: np.ndarray) -> None:
        key = q.tobytes()
        if self._placed != key:
            self.bodies.place(q)
            self._placed = key
            self.configs += 1

    def _pair(self, x: Body, y: Body) -> float:
        res = self._res
        res.clear()
        bodies = self.bodies
        return coal.distance(x.geometry, bodies.transform(x), y.geometry, bodies.transform(y), self._req,
                             res) / MM - GJK_EPS_MM

    def _query(self, item: _Item, q: np.ndarray, need_mm: float = 0.0) -> _Probe:
        """A distance lower bound at ``q``: a pair's distance, or a body's to everything in its tree."""
        self._place(q)
        if item.other is not None:
            return _Probe(self._pair(item.body, item.other), item.other.name)
        obj = self.bodies.placed_object(item.body)
        cb = self._cb
        if not item.tip:          # the layer boxes first: cheap, and enough when far (the bead tree is slow then)
            cb.data.clear()
            self.trees.coarse.distance(obj, cb)
            d = float(cb.data.result.min_distance) / MM - GJK_EPS_MM
            if d > need_mm:
                return _Probe(d)
        cb.data.clear()
        assert item.tree is not None, "a body item walks a tree"
        item.tree.distance(obj, cb)
        return _Probe(float(cb.data.result.min_distance) / MM - GJK_EPS_MM)

    def _probe(self, item: _Item, k: int, q: np.ndarray, need_mm: float = float("inf")) -> _Probe:
        """A distance lower bound at ``q`` for segment ``k``: from the tree; where that says touching, the
        exact distance (a bead laid later in the stretch, or an exempt one, may be what is close)."""
        p = self._query(item, q, need_mm)
        if item.other is not None or p.d > 2.0 * self.tol:
            return p
        return self._exact(item, k, q, EXACT_MARGIN_MM)

    def _exact(self, item: _Item, k: int, q: np.ndarray, margin_mm: float) -> _Probe:
        """The distance at ``q`` with exactly what the row of segment ``k`` may touch: the table, the plate
        and the beads laid before that row (for the tip, not those of its two exempt layers). Beads farther
        than ``margin_mm`` from the body's bounding box count as ``margin_mm`` away (a lower bound)."""
        self._place(q)
        if item.other is not None:
            return _Probe(self._pair(item.body, item.other), item.other.name, exact=True)
        bodies, body = self.bodies, item.body
        tf = bodies.transform(body)
        best = _Probe(float("inf"), exact=True)
        req, res = self._req, self._res
        for name, obj in bodies.env.items():
            res.clear()
            d = coal.distance(body.geometry, tf, obj.collisionGeometry(), obj.getTransform(), req, res) / MM
            if d - GJK_EPS_MM < best.d:
                best = _Probe(d - GJK_EPS_MM, name, exact=True)
        beads = self.beads
        if len(beads):
            row = int(self.segs.row[k])
            upto = len(beads) if row >= LIVE_ROW else int(np.searchsorted(beads.row, row, "left"))
            aabb = bodies.placed_object(body).getAABB()
            lo, hi = np.asarray(aabb.min_) / MM, np.asarray(aabb.max_) / MM
            mask = None
            if item.tip and int(self.segs.tip_layer[k]) >= 0:
                layer = int(self.segs.tip_layer[k])
                mask = (beads.layer[:upto] != layer) & (beads.layer[:upto] != layer - 1)
            near = beads.near(lo, hi, margin_mm, mask, upto)
            if best.d > margin_mm and len(near) == 0:
                best = _Probe(margin_mm, "part", exact=True)
            for i, obj in zip(near.tolist(), beads.objects(near), strict=True):
                res.clear()
                d = coal.distance(body.geometry, tf, obj.collisionGeometry(), obj.getTransform(), req, res) / MM
                if d - GJK_EPS_MM < best.d:
                    best = _Probe(d - GJK_EPS_MM, "part", i, exact=True)
        return best

    def _hit(self, item: _Item, k: int, s: float, q: np.ndarray, probe: _Probe) -> SweepHit:
        return SweepHit(k, int(self.segs.row[k]), float(s), item.body.name, probe.other or "?", float(probe.d),
                        np.asarray(q, dtype=float).copy(), probe.bead)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Runs of True segments as (first vertex, last vertex) pairs."""
    if not mask.any():
        return []
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    return [(int(s), int(e)) for s, e in zip(starts, ends, strict=True)]

