"""Conservative advancement along a sweep's path: distance lower bounds against motion bounds.

An *item* is a robot body against what it may touch (the table, the plate and
the beads laid before the motion; the tip without its exempt layers), or two
robot bodies that are not neighbours. A piece of the path is certified for an
item when the item's distance lower bound ``d`` at the start of the piece
exceeds the bound ``M`` on how far any point of the body moves over it
(relative to the other body for a pair): it cannot reach anything it was not
already closer to. Walking along the path, one distance certifies the
following segments up to a total motion of ``d`` (less twice the tolerance),
so far bodies take few queries. The walks of all items share one placement
of the robot per configuration.

A single segment that moves further than the clearance is bisected at the
exact midpoint of the twin's path (:meth:`Segments.q_at`). A piece is
certified when ``(d_a + d_b - M) / 2`` (a lower bound of the clearance all
along it, as ``M`` bounds the sum of any point's distances to both ends) is
above the tolerance and at least half the smaller end distance (so the
clearance reported means something); a sample at the tolerance or closer, or
a piece whose motion is down to the tolerance and still not certified, is a
hit, and the walk of that item stops there.

Distances come from the broad phase (:mod:`fabric.collision.trees`): the layer
boxes, then the beads, each a lower bound of the next. They hold every bead
laid before the stretch's end, a superset for each row in it; where they say
touching, the exact distance is taken: the table, the plate and exactly the
beads laid before the row (for the tip, not its two exempt layers), found by
their bounding boxes, each measured with coal. An exact distance holds for
its own row only, so it certifies its own segment and no further.
"""
from __future__ import annotations

import heapq
from dataclasses import dataclass

import coal
import numpy as np

from fabric.collision.beads import BeadSolids
from fabric.collision.bodies import MM, Body, RobotBodies
from fabric.collision.path import LIVE_ROW, Segments
from fabric.collision.trees import PartTrees

__all__ = ["Advancer", "Item", "Probe", "SweepHit", "GJK_EPS_MM", "EXACT_MARGIN_MM"]

GJK_EPS_MM = 1e-3            # coal's distances are within 1 um (GJK tolerance): bounds give that away
EXACT_MARGIN_MM = 2.0        # an exact query looks this far around a body for beads
_MAX_DEPTH = 60              # bisections of one segment


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
class Probe:
    d: float
    other: str = ""
    bead: int = -1
    exact: bool = False          # with exactly the beads laid before the row (else the stretch's superset)


@dataclass
class Item:
    """A body against the part and the fixed bodies (``other`` None), or two robot bodies."""

    name: str
    body: Body
    other: Body | None
    rate_mm: np.ndarray          # (nq,) joint bound per rad of each joint (relative for a pair)
    tip: bool = False            # the exempt tip: its own layer boxes, exact queries without its layers


class Advancer:
    """The walks and refinements of one sweep (see the module docstring)."""

    def __init__(self, bodies: RobotBodies, segs: Segments, beads: BeadSolids, trees: PartTrees,
                 tolerance_mm: float) -> None:
        self.bodies, self.segs, self.beads, self.trees = bodies, segs, beads, trees
        self.tol = tolerance_mm
        self.configs = 0
        self.clearance, self.clearance_body, self.clearance_segment = float("inf"), "", -1
        self._placed: bytes | None = None
        self._req = coal.DistanceRequest()
        self._res = coal.DistanceResult()
        self._cb = coal.DistanceCallBackDefault()
        self._a = 0
        self._parts: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def bound(self, lb: float, name: str, segment: int) -> None:
        """Keep the smallest certified clearance lower bound, with its body and segment."""
        if lb < self.clearance:
            self.clearance, self.clearance_body, self.clearance_segment = lb, name, segment

    # --- motion bounds of a stretch -------------------------------------------------------------

    def set_stretch(self, a: int, b: int) -> None:
        """Motion bounds of every body over segments [a, b): (J, C, E) per body (joint bound, chord part,
        chord error; :meth:`RobotBodies.chord_parts_mm`), from one vectorised FK of the stretch."""
        segs, bodies = self.segs, self.bodies
        self.frames = bodies.joint_frames(np.vstack([segs.q0[a:b], segs.q1[b - 1:b]]))
        dq = segs.dq_abs[a:b]
        self._a = a
        self._parts = {}
        for body in bodies.bodies:
            if body.joint == 0:                                # on the base: does not move
                zero = np.zeros(b - a)
                self._parts[body.name] = (zero, zero, zero)
                continue
            C, E = bodies.chord_parts_mm(bodies.body_poses(self.frames, body), body, dq)
            self._parts[body.name] = (bodies.motion_mm(dq, body), C, E)

    def _item_parts(self, item: Item) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        J, C, E = self._parts[item.body.name]
        if item.other is None:
            return J, C, E
        _, C2, E2 = self._parts[item.other.name]
        return self.segs.dq_abs[self._a:self._a + len(J)] @ item.rate_mm, C + C2, E + E2

    def motion(self, item: Item) -> np.ndarray:
        """Per segment of the stretch: how far the item's body can move (a pair: relative to the other)."""
        J, C, E = self._item_parts(item)
        linear = ~self.segs.joint[self._a:self._a + len(J)]
        return np.where(linear, np.minimum(J, C + 2.0 * E), J)

    def piece_motion(self, item: Item, k: int, sa: float, sb: float, qa: np.ndarray, qb: np.ndarray) -> float:
        """The motion bound of the piece [sa, sb] of segment ``k`` (in the current stretch)."""
        segs = self.segs
        joint = float(np.abs(qb - qa) @ item.rate_mm)
        if segs.joint[k]:
            return joint                                   # the joints move monotonically: travel = difference
        J, C, E = (float(v[k - self._a]) for v in self._item_parts(item))
        span = float(segs.s1[k] - segs.s0[k])
        f = (sb - sa) / span if span > 0 else 1.0
        return min(joint, f * C + 4.0 * E) if f < 1.0 else min(joint, C + 2.0 * E)

    # --- the walk ---------------------------------------------------------------------------------

    def walk(self, a: int, b: int, work: list[tuple[Item, np.ndarray]]) -> list[SweepHit]:
        """Walk every item over the segments of [a, b) its mask selects; the first hit of each item."""
        segs = self.segs
        state, heap = [], []
        for j, (item, mask) in enumerate(work):
            runs = _runs(mask)
            cum = np.concatenate([[0.0], np.cumsum(self.motion(item))])
            state.append({"runs": runs, "run": 0, "cum": cum, "prev": None})
            if runs:
                heap.append((runs[0][0], j))
        heapq.heapify(heap)
        hits: list[SweepHit] = []
        while heap:
            i, j = heapq.heappop(heap)
            st, item = state[j], work[j][0]
            r1 = st["runs"][st["run"]][1]
            cum = st["cum"]
            if i >= r1:                                     # end of a run: close its last stretch, go on
                if st["prev"] is not None:
                    end = segs.q1[a + i - 1]
                    self._close(item, st, i, self._query(item, end), a + i - 1)
                st["prev"] = None
                st["run"] += 1
                if st["run"] < len(st["runs"]):
                    heapq.heappush(heap, (st["runs"][st["run"]][0], j))
                continue
            k = a + i
            q = segs.q0[k]
            step = float(cum[i + 1] - cum[i])
            probe = self.probe(item, k, q, step + 2.0 * self.tol)
            if st["prev"] is not None:
                self._close(item, st, i, probe, k)
            if probe.d <= self.tol:
                hits.append(self.hit(item, k, float(segs.s0[k]), q, probe))
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
            h = self.refine(item, k, float(segs.s0[k]), q, probe, float(segs.s1[k]), q1,
                            self.probe(item, k, q1, step + 2.0 * self.tol), 0, step)
            if h is not None:
                hits.append(h)
                continue
            heapq.heappush(heap, (i + 1, j))
        return hits

    def _close(self, item: Item, st: dict, i: int, probe: Probe, k: int) -> None:
        """The clearance lower bound of the stretch certified from the item's last query to vertex ``i``."""
        pi, pd = st["prev"]
        span = float(st["cum"][i] - st["cum"][pi])
        self.bound(max(pd - span, (pd + probe.d - span) / 2.0), item.name, k)

    def refine(self, item: Item, k: int, sa: float, qa: np.ndarray, pa: Probe, sb: float, qb: np.ndarray,
               pb: Probe, depth: int = 0, motion: float | None = None) -> SweepHit | None:
        """Certify segment ``k`` between fractions ``sa`` and ``sb`` by bisection, or find where it touches."""
        if pa.d <= self.tol:
            return self.hit(item, k, sa, qa, pa)
        if motion is None:
            motion = self.piece_motion(item, k, sa, sb, qa, qb)
        lb = (pa.d + pb.d - motion) / 2.0
        if lb > self.tol and (lb >= 0.5 * min(pa.d, pb.d) or motion <= self.tol):
            self.bound(lb, item.name, k)
            return None
        if motion <= self.tol or depth >= _MAX_DEPTH:
            s, q, p = (sa, qa, pa) if pa.d <= pb.d else (sb, qb, pb)
            return self.hit(item, k, s, q, p)
        sm = (sa + sb) / 2.0
        qm = self.segs.q_at(k, sm)
        pm = self.probe(item, k, qm, motion / 2.0 + 2.0 * self.tol)
        left = self.refine(item, k, sa, qa, pa, sm, qm, pm, depth + 1)
        if left is not None:
            return left
        return self.refine(item, k, sm, qm, pm, sb, qb, pb, depth + 1)

    # --- distances ----------------------------------------------------------------------------------

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

    def _tree_distance(self, tree: coal.BroadPhaseCollisionManager, obj: coal.CollisionObject) -> float:
        cb = self._cb
        cb.data.clear()
        tree.distance(obj, cb)
        return float(cb.data.result.min_distance) / MM - GJK_EPS_MM

    def _query(self, item: Item, q: np.ndarray, need_mm: float = 0.0) -> Probe:
        """A distance lower bound at ``q``: a pair's distance; a body's to the layer boxes, and to the beads
        when the boxes are not far enough for ``need_mm``."""
        self._place(q)
        if item.other is not None:
            return Probe(self._pair(item.body, item.other), item.other.name, exact=True)
        obj = self.bodies.placed_object(item.body)
        if item.tip:
            return Probe(self._tree_distance(self.trees.coarse_tip, obj))
        d = self._tree_distance(self.trees.coarse, obj)
        if d > need_mm:
            return Probe(d)
        return Probe(self._tree_distance(self.trees.fine_tree(), obj))

    def probe(self, item: Item, k: int, q: np.ndarray, need_mm: float = float("inf")) -> Probe:
        """A distance lower bound at ``q`` for segment ``k``: from the trees; where they say touching, the
        exact distance (a bead laid later in the stretch, or an exempt one, may be what is close)."""
        p = self._query(item, q, need_mm)
        if item.other is not None or p.d > 2.0 * self.tol:
            return p
        return self.exact(item, k, q, EXACT_MARGIN_MM)

    def exact(self, item: Item, k: int, q: np.ndarray, margin_mm: float) -> Probe:
        """The distance at ``q`` with exactly what the row of segment ``k`` may touch: the table, the plate
        and the beads laid before that row (for the tip, not those of its two exempt layers). Beads farther
        than ``margin_mm`` from the body's bounding box count as ``margin_mm`` away (a lower bound)."""
        self._place(q)
        if item.other is not None:
            return Probe(self._pair(item.body, item.other), item.other.name, exact=True)
        bodies, body = self.bodies, item.body
        tf = bodies.transform(body)
        best = Probe(float("inf"), exact=True)
        req, res = self._req, self._res
        for name, obj in bodies.env.items():
            res.clear()
            d = coal.distance(body.geometry, tf, obj.collisionGeometry(), obj.getTransform(), req, res) / MM
            if d - GJK_EPS_MM < best.d:
                best = Probe(d - GJK_EPS_MM, name, exact=True)
        beads = self.beads
        if len(beads):
            row = int(self.segs.row[k])
            upto = len(beads) if row >= LIVE_ROW else int(np.searchsorted(beads.row, row, "left"))
            aabb = bodies.placed_object(body).getAABB()
            lo, hi = np.asarray(aabb.min_) / MM, np.asarray(aabb.max_) / MM
            mask = None
            layer = int(self.segs.tip_layer[k])
            if item.tip and layer >= 0:
                mask = (beads.layer[:upto] != layer) & (beads.layer[:upto] != layer - 1)
            near = beads.near(lo, hi, margin_mm, mask, upto)
            if best.d > margin_mm:
                best = Probe(margin_mm, "part", exact=True)
            for i, obj in zip(near.tolist(), beads.objects(near), strict=True):
                res.clear()
                d = coal.distance(body.geometry, tf, obj.collisionGeometry(), obj.getTransform(), req, res) / MM
                if d - GJK_EPS_MM < best.d:
                    best = Probe(d - GJK_EPS_MM, "part", i, exact=True)
        return best

    def hit(self, item: Item, k: int, s: float, q: np.ndarray, probe: Probe) -> SweepHit:
        if not probe.exact:                                 # name what is touched
            probe = self.exact(item, k, q, EXACT_MARGIN_MM)
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
