"""Conservative advancement along a sweep's path: distance lower bounds against motion bounds.

An *item* is a robot body against what it may touch (the table, the plate and
the beads laid before the motion; the tip without its exempt layers), or two
robot bodies that are not neighbours. A piece of the path is certified for an
item when the item's distance lower bound ``d`` at the start of the piece
exceeds the bound ``M`` on how far any point of the body moves over it
(relative to the other body for a pair): it cannot reach anything it was not
already closer to. Walking along the path, one distance certifies the
following segments up to a total motion of ``d`` (less twice the tolerance),
so far bodies take few queries. The motion bound of a pair counts only the
joints that do not move both bodies (turning both together changes nothing
between them). The walks of all items go in path order (the broad phase
follows) and share one placement of the robot per configuration.

A first pass gives a distance lower bound at every configuration for free:
a few spheres covering each body against the bounding boxes of the fixed
bodies and of the part laid so far (for a pair, one sphere around each). Where
those bounds alone carry the walk on, it jumps along them (all vertices'
jumps are found at once by pointer doubling), and coal is asked only where
they run out.

A single segment that moves further than the clearance is bisected at the
exact midpoint of the twin's path (:meth:`Segments.q_at`). A piece is
certified when ``(d_a + d_b - M) / 2`` (a lower bound of the clearance all
along it, as ``M`` bounds the sum of any point's distances to both ends) is
above the tolerance and at least half the smaller end distance (so the
clearance reported means something); a sample at the tolerance or closer, or
a piece whose motion is down to the tolerance and still not certified, is a
hit, and the walk of that item stops there.

Distances come from the broad phase (:mod:`fabric.collision.trees`): the
part's boxes, then the beads' chains (for the tip, without its exempt
layers), each a lower bound of the next. The boxes hold every bead laid
before the stretch's end, the chains every bead laid before the row asked
about (they follow the path), a superset for each row; where they say
touching, the exact distance is taken: the table, the plate and exactly the
beads laid before the row (for the tip, not its exempt layers), found by
their bounding boxes in a grid, nearest first (those within
``EXACT_NEAR_MM`` first: if one is nearer than that, no other can be), each
measured with coal. An exact distance holds for its own row only, so it
certifies its own segment and no further.
"""
from __future__ import annotations

import heapq
from collections.abc import Callable
from dataclasses import dataclass

import coal
import numpy as np

from fabric.collision.beads import BeadSolids
from fabric.collision.bodies import GJK_EPS_MM, MM, Body, RobotBodies
from fabric.collision.path import LIVE_ROW, NO_LAYER, Segments
from fabric.collision.trees import PartTrees

__all__ = ["Advancer", "Item", "Probe", "SweepHit", "GJK_EPS_MM", "EXACT_MARGIN_MM"]

EXACT_MARGIN_MM = 2.0        # an exact query looks this far around a body for beads
EXACT_NEAR_MM = 0.5          # first this far: where a bead is nearer, no farther one can be
FINE_BELOW_MM = 5.0          # the beads' tree is asked only when the layer boxes are this close
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
    exact: bool = False          # with exactly what the row may touch (else the stretch's superset)
    row_only: bool = False       # holds for this row only (exact beads laid before it): certifies no further


@dataclass
class _Walk:
    """One item's walk: its runs of vertices, which it is on, cumulative motion and first-pass bounds per
    vertex, and its last query (vertex, distance) while a stretch certified by it is open."""

    runs: list[tuple[int, int]]
    cum: np.ndarray
    free: np.ndarray
    stop: np.ndarray                        # per vertex: where the first pass's bounds alone certify on to
    low: np.ndarray                         # and the smallest clearance they certify on the way
    run: int = 0
    prev: tuple[int, float] | None = None


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
        self._collide_cb = coal.CollisionCallBackDefault()
        self._a = 0
        self._parts: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def bound(self, lb: float, name: str, segment: int) -> None:
        """Keep the smallest certified clearance lower bound, with its body and segment."""
        if lb < self.clearance:
            self.clearance, self.clearance_body, self.clearance_segment = lb, name, segment

    # --- a batch of segments: motion bounds and first-pass distances, vectorised ---------------------

    def set_batch(self, a: int, b: int, part_lo: np.ndarray, part_hi: np.ndarray) -> None:
        """Segments [a, b): every body's motion bound per segment (:meth:`RobotBodies.motion_mm`) and the
        spheres covering it at every vertex, from one vectorised FK; ``part_lo``/``part_hi`` (b - a + 1, 3)
        bound the part laid by each vertex's stretch."""
        segs, bodies = self.segs, self.bodies
        frames = bodies.joint_frames(np.vstack([segs.q0[a:b], segs.q1[b - 1:b]]))
        dq = segs.dq_abs[a:b]
        self._a = a
        self._motion: dict[str, np.ndarray] = {}
        self.spheres: dict[str, tuple[np.ndarray, float]] = {}
        self.sphere: dict[str, tuple[np.ndarray, float]] = {}
        for body in bodies.bodies:
            poses = bodies.body_poses(frames, body)
            self.spheres[body.name] = bodies.spheres(poses, body)
            self.sphere[body.name] = bodies.sphere(poses, body)
            self._motion[body.name] = bodies.motion_mm(dq, body)
        env_lo, env_hi = self.trees.env_lo, self.trees.env_hi
        self._box_lo = np.concatenate([np.broadcast_to(env_lo, (len(part_lo), *env_lo.shape)), part_lo[:, None]], 1)
        self._box_hi = np.concatenate([np.broadcast_to(env_hi, (len(part_hi), *env_hi.shape)), part_hi[:, None]], 1)

    def free(self, item: Item, at: np.ndarray | slice = slice(None)) -> np.ndarray:
        """A distance lower bound at the vertices ``at`` of the batch, from the spheres covering each body:
        to the bounding boxes of the fixed bodies and of the part laid so far (for a pair, the sphere
        around each body's box to the other's). Cheap, vectorised, and enough for bodies far from
        everything."""
        c, r = self.spheres[item.body.name]                                           # (N, k, 3)
        c = c[at]
        if item.other is None:
            lo, hi = self._box_lo[at], self._box_hi[at]                             # (N, B, 3)
            gap = np.maximum(np.maximum(lo[:, None] - c[:, :, None], c[:, :, None] - hi[:, None]), 0.0)
            return np.sqrt(np.square(gap).sum(axis=3).min(axis=(1, 2))) - r
        (c1, r1), (c2, r2) = self.sphere[item.body.name], self.sphere[item.other.name]   # one each: enough
        return np.linalg.norm(c1[at] - c2[at], axis=1) - r1 - r2                     # for pairs, far or not

    def motion(self, item: Item) -> np.ndarray:
        """Per segment of the batch: how far the item's body can move; for a pair, relative to the other
        (the joint bound of the joints that do not move both: turning both together changes nothing)."""
        if item.other is None:
            return self._motion[item.body.name]
        n = len(self._motion[item.body.name])
        return self.segs.dq_abs[self._a:self._a + n] @ item.rate_mm

    def piece_motion(self, item: Item, k: int, sa: float, sb: float, qa: np.ndarray, qb: np.ndarray) -> float:
        """The motion bound of the piece [sa, sb] of segment ``k``: the joints move monotonically (a linear
        move's interpolation, a rest-to-rest joint move), so a joint travels the difference of the ends."""
        return float(np.abs(qb - qa) @ item.rate_mm)

    # --- the walk ---------------------------------------------------------------------------------

    def walk(self, a: int, b: int, work: list[tuple[Item, list[tuple[int, int]]]],
             enter: Callable[[int], list[SweepHit]], stretch_of: np.ndarray) -> list[SweepHit]:
        """Walk every item over its runs of vertices (batch-local, ``(first, last)``) in [a, b), in path
        order, calling ``enter(s)`` before the first vertex of each stretch ``s`` (``stretch_of``: per
        segment of the batch). The walk stops once no item can find a hit before the earliest one found.
        Returns every hit found (at most one per item, and ``enter``'s)."""
        segs = self.segs
        n = b - a
        state: list[_Walk] = []
        heap: list[tuple[int, int]] = []
        for j, (item, runs) in enumerate(work):
            cum = np.concatenate([[0.0], np.cumsum(self.motion(item))])
            covered = sum(r1 - r0 + 1 for r0, r1 in runs)
            if covered < (n + 1) // 4:                      # a few short runs (joint moves): just those vertices
                at = np.concatenate([np.arange(r0, r1 + 1) for r0, r1 in runs]) if runs else np.zeros(0, int)
                free = np.full(n + 1, -np.inf)
                free[at] = self.free(item, at)
            else:
                free = self.free(item)
            stop, low = self._chains(cum, free, runs)
            state.append(_Walk(runs, cum, free, stop, low))
            if runs:
                heap.append((runs[0][0], j))
        heapq.heapify(heap)
        hits: list[SweepHit] = []
        best = n + 1                                        # local segment of the earliest hit so far
        entered = int(stretch_of[0]) - 1
        while heap and heap[0][0] <= best:
            i, j = heapq.heappop(heap)
            here = int(stretch_of[min(i, n - 1)])
            while entered < here:                           # the broad phase follows the path
                entered += 1
                found = enter(entered)
                hits += found
                best = min([best] + [h.segment - a for h in found])
            if i > best:
                continue
            st, item = state[j], work[j][0]
            r1 = st.runs[st.run][1]
            cum, free = st.cum, st.free
            if i >= r1:                                     # end of a run: close its last stretch, go on
                if st.prev is not None:
                    end = float(free[i]) if free[i] > 0 else self.probe(item, a + i - 1, segs.q1[a + i - 1]).d
                    self._close(item, st, i, Probe(end), a + i - 1)
                st.prev = None
                st.run += 1
                if st.run < len(st.runs):
                    heapq.heappush(heap, (st.runs[st.run][0], j))
                continue
            k = a + i
            q = segs.q0[k]
            step = float(cum[i + 1] - cum[i])
            v = int(st.stop[i])
            if v > i:                                       # the first pass's bounds certify on to vertex v
                if st.prev is not None:
                    self._close(item, st, i, Probe(float(free[i])), k)
                st.prev = None
                self.bound(float(st.low[i]), item.name, k)
                heapq.heappush(heap, (v, j))
                continue
            probe = self.probe(item, k, q, step + 2.0 * self.tol)
            if st.prev is not None:
                self._close(item, st, i, probe, k)
            if probe.d <= self.tol:
                hits.append(self.hit(item, k, float(segs.s0[k]), q, probe))
                best = min(best, i)
                continue                                    # this item stops at its first hit
            # an exact distance holds for this segment's row only: it may certify this segment, no further
            last = i + 1 if probe.row_only else r1
            u = min(int(np.searchsorted(cum, cum[i] + probe.d - 2.0 * self.tol, "left")) - 1, last)
            if u > i:                                       # certified up to vertex u by this one distance
                st.prev = (i, probe.d)
                heapq.heappush(heap, (u, j))
                continue
            st.prev = None                                  # segment i moves further than the clearance: bisect
            q1 = segs.q1[k]
            h = self.refine(item, k, float(segs.s0[k]), q, probe, float(segs.s1[k]), q1,
                            self.probe(item, k, q1, step + 2.0 * self.tol), 0, step)
            if h is not None:
                hits.append(h)
                best = min(best, i)
                continue
            heapq.heappush(heap, (i + 1, j))
        return hits

    def _chains(self, cum: np.ndarray, free: np.ndarray, runs: list[tuple[int, int]],
                ) -> tuple[np.ndarray, np.ndarray]:
        """Where the first pass's bounds alone take the walk from each vertex, and the smallest clearance
        they certify on the way: from vertex ``i`` a bound ``free[i]`` certifies on to the last vertex ``u``
        of its run with ``cum[u] - cum[i] < free[i] - 2 tol`` (with clearance ``max(free[i] - span,
        (free[i] + free[u] - span) / 2)``), then from ``u`` again, until a vertex whose bound does not take
        it one segment on. Followed for every vertex at once by pointer doubling."""
        n = len(cum)
        end = np.arange(n)
        for r0, r1 in runs:
            end[r0:r1] = r1
        nxt = np.searchsorted(cum, cum + free - 2.0 * self.tol, "left") - 1
        nxt = np.clip(np.minimum(nxt, end), np.arange(n), None)          # never back, never past the run
        span = cum[nxt] - cum
        low = np.where(nxt > np.arange(n), np.maximum(free - span, (free + free[nxt] - span) / 2.0), np.inf)
        for _ in range(max(1, int(np.ceil(np.log2(max(n, 2)))))):
            low = np.minimum(low, low[nxt])
            after = nxt[nxt]
            if np.array_equal(after, nxt):                 # every chain has reached its stop
                break
            nxt = after
        return nxt, low

    def _close(self, item: Item, st: _Walk, i: int, probe: Probe, k: int) -> None:
        """The clearance lower bound of the stretch certified from the item's last query to vertex ``i``."""
        assert st.prev is not None, "a stretch is open"
        pi, pd = st.prev
        span = float(st.cum[i] - st.cum[pi])
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
        pm = self.probe(item, k, qm, min(motion / 2.0, FINE_BELOW_MM) + 2.0 * self.tol)
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
            self._tf: dict[str, coal.Transform3s] = {}
            self.configs += 1

    def _transform(self, body: Body) -> coal.Transform3s:
        tf = self._tf.get(body.name)
        if tf is None:
            tf = self._tf[body.name] = self.bodies.transform(body)
        return tf

    def _pair(self, x: Body, y: Body) -> float:
        res = self._res
        res.clear()
        return coal.distance(x.geometry, self._transform(x), y.geometry, self._transform(y), self._req,
                             res) / MM - GJK_EPS_MM

    def _tree_distance(self, tree: coal.BroadPhaseCollisionManager, obj: coal.CollisionObject) -> float:
        cb = self._cb
        cb.data.clear()
        tree.distance(obj, cb)
        return float(cb.data.result.min_distance) / MM - GJK_EPS_MM

    def cylinder_distance(self, tree: coal.BroadPhaseCollisionManager, centre: np.ndarray, rotation: np.ndarray,
                          radius_mm: float, half_mm: float) -> float:
        """The distance (mm, a lower bound) from a cylinder (centre, rotation whose z is its axis, radius,
        half-length; mm) to what ``tree`` holds: a cover of the tool's sweep
        (:func:`fabric.collision.hull.piece_covers`)."""
        obj = coal.CollisionObject(coal.Cylinder(radius_mm * MM, 2.0 * half_mm * MM), rotation, centre * MM)
        obj.computeAABB()
        return self._tree_distance(tree, obj)

    def cylinder_clear(self, tree: coal.BroadPhaseCollisionManager, centre: np.ndarray, rotation: np.ndarray,
                       radius_mm: float, half_mm: float, margin_mm: float) -> bool:
        """Whether a cylinder (as :meth:`cylinder_distance`) is farther than ``margin_mm`` from everything
        ``tree`` holds: the cylinder grown by the margin (and coal's tolerance) along and across touches
        nothing. Cheaper than the distance: coal stops at the first contact, or sees none."""
        grow = margin_mm + GJK_EPS_MM
        obj = coal.CollisionObject(coal.Cylinder((radius_mm + grow) * MM, 2.0 * (half_mm + grow) * MM), rotation,
                                   centre * MM)
        obj.computeAABB()
        cb = self._collide_cb
        cb.data.clear()
        tree.collide(obj, cb)
        return not cb.data.result.isCollision()

    def upto(self, k: int) -> int:
        """How many beads are laid before the row of segment ``k``."""
        row = int(self.segs.row[k])
        return len(self.beads) if row >= LIVE_ROW else int(np.searchsorted(self.beads.row, row, "left"))

    def upto_many(self, k: np.ndarray) -> np.ndarray:
        """:meth:`upto` of segments ``k``."""
        row = self.segs.row[k]
        return np.where(row >= LIVE_ROW, len(self.beads), np.searchsorted(self.beads.row, row, "left"))

    def _query(self, item: Item, k: int, q: np.ndarray, need_mm: float = 0.0) -> Probe:
        """A distance lower bound at ``q``: a pair's distance; a body's to the layer boxes, and to the beads
        when the boxes are not far enough for ``need_mm``."""
        self._place(q)
        if item.other is not None:
            return Probe(self._pair(item.body, item.other), item.other.name, exact=True)
        obj = self.bodies.placed_object(item.body)
        d = self._tree_distance(self.trees.coarse_tip if item.tip else self.trees.coarse, obj)
        if d > need_mm or d > FINE_BELOW_MM:       # far from the layer boxes: bisecting is cheaper than beads
            return Probe(d)
        if self.trees.fine_too_big():               # a tree that big takes longer to build than to go exact
            return Probe(-1.0)
        upto = self.upto(k)
        fine = self.trees.fine_tip_tree(upto) if item.tip else self.trees.fine_tree(upto)
        return Probe(self._tree_distance(fine, obj))

    def probe(self, item: Item, k: int, q: np.ndarray, need_mm: float = float("inf")) -> Probe:
        """A distance lower bound at ``q`` for segment ``k``: from the trees; where they say touching, the
        exact distance (a bead laid later in the stretch, or an exempt one, may be what is close)."""
        p = self._query(item, k, q, need_mm)
        if item.other is not None or p.d > 2.0 * self.tol:
            return p
        margin = EXACT_MARGIN_MM if not np.isfinite(need_mm) else max(EXACT_MARGIN_MM, need_mm)
        return self.exact(item, k, q, margin)

    def exact(self, item: Item, k: int, q: np.ndarray, margin_mm: float) -> Probe:
        """The distance at ``q`` with exactly what the row of segment ``k`` may touch: the table, the plate
        and the beads laid before that row (for the tip, not those of its exempt layers). Beads farther
        than ``margin_mm`` from the body's bounding box count as ``margin_mm`` away (a lower bound)."""
        self._place(q)
        if item.other is not None:
            return Probe(self._pair(item.body, item.other), item.other.name, exact=True)
        bodies, body = self.bodies, item.body
        tf = self._transform(body)
        best = Probe(float("inf"), exact=True, row_only=True)
        req, res = self._req, self._res
        for name, obj in bodies.env.items():
            res.clear()
            d = coal.distance(body.geometry, tf, obj.collisionGeometry(), obj.getTransform(), req, res) / MM
            if d - GJK_EPS_MM < best.d:
                best = Probe(d - GJK_EPS_MM, name, exact=True, row_only=True)
        beads = self.beads
        if len(beads):
            upto = self.upto(k)
            aabb = bodies.placed_object(body).getAABB()
            lo, hi = np.asarray(aabb.min_) / MM, np.asarray(aabb.max_) / MM
            layer = int(self.segs.tip_layer[k])
            skip = beads.exempt_layers(layer) if item.tip and layer != NO_LAYER else ()
            for m in (EXACT_NEAR_MM, margin_mm) if margin_mm > EXACT_NEAR_MM else (margin_mm,):
                # nearest bounding box first: a bead whose box is no nearer than the best so far is not nearer
                near = beads.near(lo, hi, m, upto, skip)
                gap = np.linalg.norm(np.maximum(np.maximum(beads.lo[near] - hi, lo - beads.hi[near]), 0.0), axis=1)
                order = np.argsort(gap, kind="stable")
                for i, g in zip(near[order].tolist(), gap[order].tolist(), strict=True):
                    if g >= best.d:
                        break
                    obj = beads.object(i)
                    res.clear()
                    d = coal.distance(body.geometry, tf, obj.collisionGeometry(), obj.getTransform(), req, res) / MM
                    if d - GJK_EPS_MM < best.d:
                        best = Probe(d - GJK_EPS_MM, "part", i, exact=True, row_only=True)
                if best.d <= m:                             # every other bead is farther than m
                    break
            if best.d > margin_mm:
                best = Probe(margin_mm, "part", exact=True, row_only=True)
        return best

    def hit(self, item: Item, k: int, s: float, q: np.ndarray, probe: Probe) -> SweepHit:
        if not probe.exact:                                 # name what is touched
            probe = self.exact(item, k, q, EXACT_MARGIN_MM)
        return SweepHit(k, int(self.segs.row[k]), float(s), item.body.name, probe.other or "?", float(probe.d),
                        np.asarray(q, dtype=float).copy(), probe.bead)
