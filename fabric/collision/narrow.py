"""The tool's swept hulls near the part: their cylinders against the beads, finer where they must be.

The swept hulls of :mod:`fabric.collision.hull` are first measured against
one box per layer. A tilted tool over a curved layer comes within the
tolerance of those boxes nearly everywhere: a box holds a piece of a curved
surface and the empty space beside it, where the tool is. Such covers are
measured here as what they are, cylinders, with coal against the beads'
chains (:meth:`fabric.collision.trees.PartTrees.fine_tree`; for the tip,
without its exempt layers), coarse to fine:

1. each cover as it is (up to 16 pieces; a wide tool, the extruder's body,
   first against balls around the chains: it is far from them);
2. the pieces of a cover that does not clear, four at a time, then one at a
   time (:func:`fabric.collision.hull.piece_covers`: the narrower the cover,
   the less its spread across a turning axis and its growth for the turn);
3. a piece that still does not clear, halved (at the exact joints the twin
   passes through) ``HALVINGS`` times.

Each cover holds every position of the tool over its pieces (grown by its
chord error and turn), and the chains hold every bead laid before the last
row of the cover (the tree follows the covers along the path), so a cover
farther than the tolerance certifies its pieces. A cover need not be
measured: one at least as far as the smallest clearance so far changes
nothing, and coal proves that much (no contact with the cylinder grown by
it) faster than it measures a distance; only where it does not hold, and no
finer cover is to come, is the distance taken and kept. What is left, in
path order, goes to the walk's bisection
(:meth:`fabric.collision.advance.Advancer.refine`), which takes exact
distances with exactly the beads laid before each row.

Covers of a tilted tool that clear the boxes, but by less than the clearance
so far, are measured too (in the same path order): their box distance is a
bound of the boxes, not of the tool, and would be the clearance reported.
Against the chains first; where that too would lower the clearance, from
exact distances at the ends of the cover's pieces, halved where the motion
between two ends is more than half their distance (the chains' boxes hold
air of their own beside a curved layer: on a ridge of curved layers the
chains gave 0.035 mm for a nozzle 0.95 mm from the beads).
"""
from __future__ import annotations

import functools
from collections.abc import Callable, Iterator

import numpy as np

from fabric.collision.advance import Advancer, Item
from fabric.collision.hull import X_REF, HullCovers, ToolCylinder, piece_covers
from fabric.collision.path import Segments
from fabric.collision.trees import PartTrees
from fabric.robot.frames import frame_from_z_axis

__all__ = ["narrow", "HALVINGS", "FLOOR_MAX_MM"]

BIG_TOOL_MM = 20.0           # a tool wider than this is first measured against balls around the chains
HALVINGS = 5                 # a piece is halved this often against the beads before the walk bisects it
EXACT_HALVINGS = 4           # a loose cover's piece is halved this often for its clearance from exact distances
EXACT_REACH_MM = 0.5         # exact queries look this far past twice the clearance (at most the piece's motion)
FLOOR_MAX_MM = 5.0           # above this, a cover's distance is taken rather than proved at least the clearance


def narrow(adv: Advancer, trees: PartTrees, segs: Segments, tool: ToolCylinder, item: Item, covers: HullCovers,
           near: np.ndarray, box_mm: np.ndarray, touch_mm: float) -> Iterator[tuple[int, float, float]]:
    """Certify covers ``near`` (indices, in path order) of ``tool``, ``box_mm`` from the boxes, against the
    beads, coarse to fine (see the module docstring), keeping each clearance with :meth:`Advancer.bound`; those
    that clear the boxes already get a clearance of their own (:func:`_tighten`). Yields the pieces left, as
    (segment, fraction from, fraction to) in path order, each before the next cover is looked at: the beads'
    tree follows the path, holding the beads laid before the last row of the cover at hand. The covers'
    cylinders are made for all of ``near`` at once; coal measures them one by one."""
    last = covers.segment[covers.edges[near + 1] - 1]
    upto_all = adv.upto_many(last)                                  # beads laid before each cover's last row
    if trees.fine_too_big():                                        # no beads' tree: the boxes, then the walk
        loose = np.flatnonzero(box_mm > touch_mm)
        if len(loose):
            i = int(loose[np.argmin(box_mm[loose])])
            adv.bound(float(box_mm[i]), tool.body.name, int(covers.segment[covers.edges[near[i]]]))
        for g in near[box_mm <= touch_mm].tolist():
            p0, p1 = int(covers.edges[g]), int(covers.edges[g + 1])
            yield from zip(covers.segment[p0:p1].tolist(), covers.s0[p0:p1].tolist(), covers.s1[p0:p1].tolist(),
                           strict=True)
        return
    tight = np.flatnonzero(box_mm <= touch_mm)                      # the covers to certify, not only to measure
    size = covers.edges[near[tight] + 1] - covers.edges[near[tight]]
    first = np.concatenate([[0], np.cumsum(size)])                  # each one's pieces in the arrays below
    pieces = np.concatenate([np.arange(covers.edges[g], covers.edges[g + 1]) for g in near[tight].tolist()]
                            or [np.zeros(0, np.int64)])
    k, s0, s1 = covers.segment[pieces], covers.s0[pieces], covers.s1[pieces]
    bodies = adv.bodies
    qa, qb = _joints(segs, k, s0), _joints(segs, k, s1)
    Ta, Tb = (bodies.cell.robot.fk(qa), bodies.cell.robot.fk(qb)) if len(k) else (np.zeros((0, 4, 4)),) * 2
    whole = _Covers(covers.centre[near], frame_from_z_axis(covers.axis[near], X_REF), covers.radius[near],
                    covers.half[near], covers.grow[near], covers.segment[covers.edges[near]])
    wide = np.flatnonzero(size == 16)                               # covers of 16 pieces: also in fours
    in16 = (first[wide][:, None] + np.arange(16)).ravel()
    if len(k):
        ones = _Covers(*piece_covers(bodies, tool, Ta, Tb, qb - qa), k)
        fours = _Covers(*piece_covers(bodies, tool, Ta[in16], Tb[in16], qb[in16] - qa[in16], 4), k[in16][::4])
    four_of = np.full(len(tight), -1)
    four_of[wide] = 4 * np.arange(len(wide))
    check = _Check(adv, tool, touch_mm)
    big = 2.0 * tool.radius_mm > BIG_TOOL_MM
    t = 0                                                           # the next of ``tight``
    for j in range(len(near)):
        upto = int(upto_all[j])
        check.tree = trees.fine_tip_tree(upto) if item.tip else trees.fine_tree(upto)
        if box_mm[j] > touch_mm:
            _tighten(check, whole, j, float(box_mm[j]),
                     functools.partial(_exact_bounds, adv, item, covers, int(near[j]), float(box_mm[j])))
            continue
        a, b = int(first[t]), int(first[t + 1])
        f0 = int(four_of[t])
        t += 1
        if big and _far(adv, trees, upto, item.tip, whole, j, touch_mm, tool.body.name):
            continue
        if check(whole, j, True):
            continue
        if f0 >= 0:
            left = [p for f in range(4) if not check(fours, f0 + f, True) for p in range(a + 4 * f, a + 4 * f + 4)]
        else:
            left = list(range(a, b))
        left = [p for p in left if not check(ones, p, HALVINGS > 0)]
        if left and HALVINGS:
            yield from _halve(check, bodies, segs, tool, k[left], s0[left], s1[left], Ta[left], Tb[left], qa[left],
                              qb[left])
        else:
            yield from ((int(k[p]), float(s0[p]), float(s1[p])) for p in left)


class _Covers:
    """Cylinders covering pieces: centre, rotation (z the axis), radius, half-length, growth; and a segment of
    each (to name where a clearance is)."""

    def __init__(self, centre: np.ndarray, rot: np.ndarray, radius: np.ndarray, half: np.ndarray, grow: np.ndarray,
                 segment: np.ndarray) -> None:
        self.centre, self.rot, self.grow, self.segment = centre, rot, grow, segment
        self.radius, self.half = radius.tolist(), half.tolist()


class _Check:
    """Does a cover clear the tree by more than the tolerance? A cover no nearer than the smallest clearance
    so far changes nothing: that much is proved where it holds (cheaper than the distance); where it does not
    and there are finer covers to come, they say more; else the distance is taken, and kept."""

    def __init__(self, adv: Advancer, tool: ToolCylinder, touch_mm: float) -> None:
        self.adv, self.name, self.touch = adv, tool.body.name, touch_mm
        self.tree = None

    def __call__(self, c: _Covers, i: int, finer: bool) -> bool:
        adv = self.adv
        args = (self.tree, c.centre[i], c.rot[i], c.radius[i], c.half[i])
        if self.touch < adv.clearance < FLOOR_MAX_MM:
            if adv.cylinder_clear(*args, adv.clearance + float(c.grow[i])):
                return True
            if finer:
                return False
        d = adv.cylinder_distance(*args) - float(c.grow[i])
        if d > self.touch:
            adv.bound(d, self.name, int(c.segment[i]))
            return True
        return False


def _tighten(check: _Check, c: _Covers, i: int, box_mm: float, exact: Callable[[], None]) -> None:
    """Cover ``i`` of a tilted tool clears the boxes by ``box_mm``, less than the clearance so far: a bound of
    the boxes, not of the tool. Keep the largest of the clearance so far (or ``FLOOR_MAX_MM``), then half of
    it, and so on, that its cylinder clears the beads by (down to its box distance): within a factor two of
    its own. Where that would lower the clearance, ``exact()`` takes its pieces' clearance from exact
    distances (:func:`_exact_bounds`) instead: beside a curved layer the chains' boxes hold air of their own,
    and the chains' figure could be the clearance reported, ten times under the tool's own."""
    margin = _margin(check, c, i, box_mm)
    if margin < min(check.adv.clearance, FLOOR_MAX_MM):
        exact()
        return
    check.adv.bound(max(margin, box_mm), check.name, int(c.segment[i]))


def _margin(check: _Check, c: _Covers, i: int, box_mm: float) -> float:
    """The largest of the clearance so far (at most ``FLOOR_MAX_MM``), its half, its quarter, ... that cover
    ``i`` clears the beads by, down to ``box_mm`` (then at most that)."""
    adv = check.adv
    args = (check.tree, c.centre[i], c.rot[i], c.radius[i], c.half[i])
    margin = min(adv.clearance, FLOOR_MAX_MM)
    while margin > box_mm and not adv.cylinder_clear(*args, margin + float(c.grow[i])):
        margin /= 2.0
    return margin


def _far(adv: Advancer, trees: PartTrees, upto: int, tip: bool, c: _Covers, i: int, touch_mm: float, name: str,
         ) -> bool:
    """Does cover ``i`` clear the balls around the chains holding beads ``0 .. upto - 1`` (for the tip, not
    its exempt layers) and the fixed bodies by more than ``touch_mm``? A wide tool (the extruder's body) is
    far from the part: the distance of each ball's centre to the cylinder, less the ball, bounds it without
    measuring boxes one by one against a cylinder whose bounding box holds half the part."""
    centre, radius = trees.chain_balls(upto, tip)
    axis = c.rot[i][:, 2]
    rel = centre - c.centre[i]
    along = rel @ axis
    across = np.linalg.norm(rel - along[:, None] * axis, axis=1)
    gap = np.hypot(np.maximum(np.abs(along) - c.half[i], 0.0), np.maximum(across - c.radius[i], 0.0)) - radius
    fixed = adv.cylinder_distance(trees.fixed, c.centre[i], c.rot[i], c.radius[i], c.half[i])
    d = min(float(gap.min(initial=np.inf)), fixed) - float(c.grow[i])
    if d > touch_mm:
        adv.bound(d, name, int(c.segment[i]))
        return True
    return False


def _halve(check: _Check, bodies, segs: Segments, tool: ToolCylinder, k: np.ndarray, s0: np.ndarray, s1: np.ndarray,
           Ta: np.ndarray, Tb: np.ndarray, qa: np.ndarray, qb: np.ndarray) -> Iterator[tuple[int, float, float]]:
    """Halve pieces that do not clear, ``HALVINGS`` times, at the exact joints the twin passes through; yield
    what is left, in path order."""
    for depth in range(HALVINGS):
        mid = (s0 + s1) / 2.0                                       # both halves, in path order
        qm = _joints(segs, k, mid)
        Tm = bodies.cell.robot.fk(qm)
        k, s0, s1 = np.repeat(k, 2), _zip(s0, mid), _zip(mid, s1)
        Ta, Tb, qa, qb = _zip(Ta, Tm), _zip(Tm, Tb), _zip(qa, qm), _zip(qm, qb)
        halves = _Covers(*piece_covers(bodies, tool, Ta, Tb, qb - qa), k)
        left = np.array([not check(halves, i, depth < HALVINGS - 1) for i in range(len(k))], dtype=bool)
        k, s0, s1, Ta, Tb, qa, qb = k[left], s0[left], s1[left], Ta[left], Tb[left], qa[left], qb[left]
        if len(k) == 0:
            return
    yield from zip(k.tolist(), s0.tolist(), s1.tolist(), strict=True)


def _exact_bounds(adv: Advancer, item: Item, covers: HullCovers, g: int, floor_mm: float) -> None:
    """The clearance of cover ``g``'s pieces from exact distances at their ends, halved (``EXACT_HALVINGS``
    times at most) until the motion between two ends takes no more than half the nearer one's distance
    (the walk's rule), each at least ``floor_mm`` (the cover's box distance, a bound of every piece). The
    chains' boxes hold air of their own beside a curved layer: a cylinder against them comes no nearer the
    tool's own clearance than that."""
    segs = adv.segs
    base = 2.0 * min(adv.clearance, FLOOR_MAX_MM)
    last: tuple[int, float, float] | None = None          # the piece before's end: the next one's start
    for p in range(int(covers.edges[g]), int(covers.edges[g + 1])):
        k, s0, s1 = int(covers.segment[p]), float(covers.s0[p]), float(covers.s1[p])
        qa, qb = segs.q_at(k, s0), segs.q_at(k, s1)
        # the queries look as far as a bound over the clearance so far needs: an exact query says "at least
        # margin" beyond it, and ends that far apart bound the piece by (2 margin - motion) / 2. (A margin of
        # twice the clearance alone fed on itself: a tip 0.3 mm clear was reported 0.02 mm clear.)
        motion = adv.piece_motion(item, k, s0, s1, qa, qb)
        margin = base + min(motion, EXACT_REACH_MM)
        da = last[2] if last is not None and last[:2] == (k, s0) else adv.exact(item, k, qa, margin).d
        db = adv.exact(item, k, qb, margin).d
        last = (k, s1, db)
        todo = [(s0, qa, da, s1, qb, db, 0)]
        while todo:
            sa, qa, da, sb, qb, db, depth = todo.pop()
            lb = (da + db - (motion if depth == 0 else adv.piece_motion(item, k, sa, sb, qa, qb))) / 2.0
            if lb >= 0.5 * min(da, db) or depth >= EXACT_HALVINGS:
                adv.bound(max(lb, floor_mm), item.name, k)
                continue
            sm = (sa + sb) / 2.0
            qm = segs.q_at(k, sm)
            dm = adv.exact(item, k, qm, margin).d
            todo += [(sm, qm, dm, sb, qb, db, depth + 1), (sa, qa, da, sm, qm, dm, depth + 1)]


def _joints(segs: Segments, k: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Joints at fractions ``s`` of the rows of linear segments ``k`` (their linear interpolation)."""
    span = segs.s1[k] - segs.s0[k]
    return segs.q0[k] + (segs.q1[k] - segs.q0[k]) * ((s - segs.s0[k]) / span)[:, None]


def _zip(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a[0], b[0], a[1], b[1], ...``"""
    return np.stack([a, b], axis=1).reshape(-1, *a.shape[1:])
