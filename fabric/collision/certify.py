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
the tip ``nozzle_clearance_mm`` up; 4 mm x 1 mm on the paper's extruder) lays
the bead under it and rests on the layer below: against the beads of the layer
it is laying and of the layers that layer rests on, and only those, it is not
checked. A layer rests on the one printed before it and on any other whose
beads lie right under its own (:mod:`fabric.collision.support`: a curved top
band's first layer lies on the ends of many core layers). The rest of the
nozzle begins where the tip ends, so it clears the bead being laid by
``nozzle_clearance_mm`` and is checked against everything. The tip is checked
against the plate, the table and every other bead: printing the first layer it
is one layer height above the plate. For a live move the tip is laying
nothing: it may only leave the beads of the last layer (and those under it)
that it rests on where the move starts, within its radius and one layer height
of the tip. The straight descent of a restart onto a layer's first point gets
the print's exemption for that layer (the layer it goes on to lay, and those
under it, on which the tip lands): no more than the sweep of the program
grants the rows that follow.

How. The path is cut into stretches where the tip's layer changes (and
where that layer's first bead is laid); as the sweep reaches each, the beads
laid up to its last row go into the broad phase (:mod:`fabric.collision.trees`).
For a batch of stretches at a time:

1. the tool's cylinders on the TCP axis (the tip, the nozzle, and the tool
   body when the TCP is on the flange axis; where it is tilted, a long
   slender nozzle as its foot, ``FOOT_MM`` long, and the rest) along linear
   moves: swept hulls,
   measured against one box per layer a stretch at a time, in numpy
   (:mod:`fabric.collision.hull`);
2. every other body, the tool's along joint moves, and every pair of robot
   bodies: conservative advancement (:mod:`fabric.collision.advance`), with a
   vectorised first pass of bounding spheres and coal where that runs out,
   bisecting where the clearance is small.

A multi-axis program tilts the nozzle over curved layers, whose boxes hold
the empty space beside a curved surface, where the tool is: hull covers that
come within the tolerance of the boxes are measured as the cylinders they are
against the beads, covers then pieces then halves (:mod:`fabric.collision.narrow`),
and only what is left goes to the second's bisection with exact distances.
A tilted tool's box distance is not its clearance: where it would be the
smallest so far, the beads give it (within a factor two). The certified
clearance is the smallest lower bound of all; the first hit is the earliest
along the path, and ends the sweep (and every tool's refinement after it).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from fabric.collision.advance import Advancer, Item, SweepHit
from fabric.collision.beads import BeadSolids
from fabric.collision.bodies import TIP, Body, RobotBodies
from fabric.collision.hull import ToolCylinder, cover_distances, hull_covers, vertical_covers
from fabric.collision.narrow import narrow
from fabric.collision.path import LIVE_ROW, NO_LAYER, START_LAYER, Segments, move_segments, program_segments
from fabric.collision.trees import PartTrees
from fabric.motion.program import Program
from fabric.robot.cell import Cell

__all__ = ["Certifier", "SweepHit", "SweepResult", "TOLERANCE_MM", "exemption_text"]

TOLERANCE_MM = 0.01          # two bodies this close count as touching
BATCH_SEGMENTS = 20_000      # stretches are prepared (vectorised bounds, hull covers) this many segments at a time
FOOT_MM = 4.0                # a slender tool longer than twice this is covered as its foot and the rest
LOOSE_BELOW_MM = 5.0         # a tilted tool's box distance below this (and the clearance) is no clearance of its own
BLOCK_COVERS = 64            # the covers near the part are refined this many at a time, every tool's, in path order


def exemption_text(bodies: RobotBodies) -> str:
    """The exemption zone in words, for reports and docs."""
    return (f"{TIP}: r {bodies.tip_radius_mm:g} mm x {bodies.tip_length_mm:g} mm at the nozzle tip, "
            f"exempt against the layer being laid and those it rests on (a live move: those it rests on at "
            f"its start, within r + one layer height)")


@dataclass
class SweepResult:
    collision_free: bool
    clearance_mm: float          # certified lower bound of the clearance (inf: nothing moved)
    clearance_body: str          # the body (or pair) where it is smallest
    clearance_segment: int       # the segment where it is smallest (-1: nothing moved)
    configs: int                 # configurations at which exact distances were computed
    pieces: int                  # swept hull pieces
    segments: int                # path segments
    beads: int
    first_hit: SweepHit | None
    elapsed_s: float
    segs: Segments | None = field(default=None, repr=False)


class Certifier:
    """Certified sweeps for one cell (see the module docstring). Not thread-safe."""

    def __init__(self, cell: Cell, tolerance_mm: float = TOLERANCE_MM) -> None:
        self.cell = cell
        self.bodies = RobotBodies(cell)
        self.tol = float(tolerance_mm)
        # the tool's cylinders on the TCP axis go by swept hulls; link_6 (also on it) is far enough above
        # the part for bounding spheres, and walks
        self.tools = [ToolCylinder(b, r, h, off) for b, r, h, off in self.bodies.axial_cylinders()
                      if b.name.startswith("tool_")]
        self._tilted_tools = [part for tool in self.tools for part in _split(tool)]
        self._hulled = {t.body.name for t in self.tools}

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
                   tip_layer: int = NO_LAYER, vel_r: float = 0.5, kind: str = "joint",
                   q_down: np.ndarray | None = None, down_layer: int = NO_LAYER) -> SweepResult:
        """Certify one joint move (as the twin times it, at ``vel_r``) against ``beads`` (all laid before), and
        with ``q_down`` the straight descent after it, from ``q_to`` to ``q_down`` (a restart's way down).

        The tip was laying layer ``tip_layer`` where the move starts (an interrupted print): the beads of
        that layer and those it rests on within the exemption zone around the tip there (the tip's radius
        and one layer height) are what it rests on, and it may leave them. On the descent the tip may touch
        the beads of ``down_layer`` and the layers under it, as when printing ``down_layer``. Every other
        bead counts."""
        t0 = time.perf_counter()
        solids = beads if beads is not None else BeadSolids.empty()
        q_from = np.asarray(q_from, dtype=float)
        down = NO_LAYER if q_down is None else down_layer
        if len(solids) and (tip_layer != NO_LAYER or down != NO_LAYER):
            solids, tip_layer, down = self._relabelled(solids, q_from, tip_layer, down)
        segs = move_segments(self.cell.robot, q_from, q_to, vel_r, kind, tip_layer, q_down, down)
        return self._sweep(segs, solids, t0)

    def _relabelled(self, beads: BeadSolids, q: np.ndarray, tip_layer: int, down_layer: int,
                    ) -> tuple[BeadSolids, int, int]:
        """The exemptions of a live move in the labels the sweep works with (the tip may touch the beads
        labelled with its segment's tip layer ``L`` or with ``L - 1``): ``beads`` relabelled, and the tip
        layers of the joint move and of the descent.

        The joint move may leave what the tip rests on at ``q`` (:meth:`_resting`); the descent may touch the
        beads of ``down_layer`` and of the layers it rests on; a bead may be both. Three labels below every layer
        say which: ``START_LAYER`` resting only, ``START_LAYER - 1`` both, ``START_LAYER - 2`` the descent's
        only. The joint move's tip layer is then ``START_LAYER`` (it may touch the first two) and the
        descent's ``START_LAYER - 1`` (the last two). Reports name beads by their own layers: they are
        given the beads as laid, not these."""
        resting = self._resting(beads, q, tip_layer) if tip_layer != NO_LAYER else np.zeros(len(beads), bool)
        descent = np.zeros(len(beads), bool)
        if down_layer != NO_LAYER:
            descent = np.isin(beads.layer, beads.exempt_layers(down_layer))
        joint_tip = START_LAYER if tip_layer != NO_LAYER else NO_LAYER
        down_tip = START_LAYER - 1 if down_layer != NO_LAYER else NO_LAYER
        if not (resting.any() or descent.any()):
            return beads, joint_tip, down_tip
        layer = beads.layer.copy()
        layer[resting & ~descent] = START_LAYER
        layer[resting & descent] = START_LAYER - 1
        layer[~resting & descent] = START_LAYER - 2
        out = BeadSolids(beads.centre, beads.axes, beads.half, layer, beads.row, beads.gcode_line)
        out._objects, out._grid = beads._objects, beads._grid
        out._rests_on = {}                                 # the labels above say all the move may touch
        return out, joint_tip, down_tip

    def _resting(self, beads: BeadSolids, q: np.ndarray, tip_layer: int) -> np.ndarray:
        """Per bead: does the tip rest on it at ``q``? Of layer ``tip_layer`` or those it rests on, within the
        tip's radius and one layer height of the tip."""
        tip = self.cell.robot.fk(q)[:3, 3]
        height = float(np.max(2.0 * beads.half[:, 2])) if len(beads) else 0.0
        reach = self.bodies.tip_radius_mm + height
        gap = np.linalg.norm(np.maximum(np.maximum(beads.lo - tip, tip - beads.hi), 0.0), axis=1)
        return (gap <= reach) & np.isin(beads.layer, beads.exempt_layers(tip_layer))

    # --- the sweep ------------------------------------------------------------------------------

    def _sweep(self, segs: Segments, beads: BeadSolids, t0: float) -> SweepResult:
        self.segs, self.beads = segs, beads
        self.trees = PartTrees(beads, self.bodies.env)
        adv = self.adv = Advancer(self.bodies, segs, beads, self.trees, self.tol)
        self.pieces = 0
        hit: SweepHit | None = None
        runs = segs.runs(self._stretch_keys())
        self._starts = np.array([a for a, _ in runs], dtype=np.int64)
        self._stretch = np.repeat(np.arange(len(runs)), [b - a for a, b in runs])
        self._counts = np.array([self._count(b) for _, b in runs], dtype=np.int64)
        part_lo, part_hi = self._part_boxes()
        first = 0
        while first < len(runs):                           # batches of whole stretches
            last = first
            while last + 1 < len(runs) and runs[last][1] - runs[first][0] < BATCH_SEGMENTS:
                last += 1
            a, b = runs[first][0], runs[last][1]
            vert = self._stretch[np.minimum(np.arange(a, b + 1), b - 1)]
            adv.set_batch(a, b, part_lo[vert], part_hi[vert])
            idx = a + np.flatnonzero(~segs.joint[a:b])
            self._tools, self._covers = hull_covers(self.bodies, segs, idx, self._stretch[idx], self.tools,
                                                    self._tilted_tools)
            hits = adv.walk(a, b, self._work(a, b), self._enter, self._stretch[a:b])
            if hits:
                hit = min(hits, key=lambda h: (h.segment, h.s))
                break
            first = last + 1
        return SweepResult(hit is None, adv.clearance, adv.clearance_body, adv.clearance_segment, adv.configs,
                           self.pieces, len(segs), len(beads), hit, time.perf_counter() - t0, segs)

    def _count(self, b: int) -> int:
        """Beads laid before the last row of the stretch ending at segment ``b``."""
        last_row = int(self.segs.row[b - 1])
        return len(self.beads) if last_row >= LIVE_ROW else int(np.searchsorted(self.beads.row, last_row, "left"))

    def _part_boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Per stretch: the bounding box of the beads laid by its end (empty: an inverted box, far away)."""
        beads = self.beads
        lo = np.full((len(self._counts), 3), np.inf)
        hi = np.full((len(self._counts), 3), -np.inf)
        has = self._counts > 0
        if len(beads) and has.any():
            lo[has] = np.minimum.accumulate(beads.lo, axis=0)[self._counts[has] - 1]
            hi[has] = np.maximum.accumulate(beads.hi, axis=0)[self._counts[has] - 1]
        return lo, hi

    def _stretch_keys(self) -> np.ndarray:
        """Per segment, what its stretch shares: the tip's layer, and whether that layer's first bead is laid
        yet (so the nozzle lifting off one layer is not held against the next layer's beads)."""
        segs, beads = self.segs, self.beads
        started = np.zeros(len(segs), bool)
        if len(beads):
            layers, first = np.unique(beads.layer, return_index=True)
            pos = np.clip(np.searchsorted(layers, segs.tip_layer), 0, len(layers) - 1)
            known = layers[pos] == segs.tip_layer
            started = known & (segs.row >= beads.row[first][pos])
        return segs.tip_layer * 2 + started

    # --- entering a stretch: the broad phase, then the tool's swept hulls -------------------------

    def _enter(self, s: int) -> list[SweepHit]:
        segs, adv, touch = self.segs, self.adv, 2.0 * self.tol
        self.trees.advance(int(self._counts[s]), int(segs.tip_layer[self._starts[s]]))
        hits: list[SweepHit] = []
        if self._covers is None:
            return hits
        g0, g1 = (int(g) for g in np.searchsorted(self._covers[0].stretch, [s, s + 1]))   # the tools share
        if g0 == g1:                                                                       # their covers
            return hits
        self.pieces += int(self._covers[0].edges[g1] - self._covers[0].edges[g0])
        near, box = [], []
        for tool, covers in zip(self._tools, self._covers, strict=True):
            lo, hi = self.trees.layer_boxes(tool.body.name == TIP)
            dist = cover_distances(covers, slice(g0, g1), lo, hi, touch)
            # a tilted tool near a box may be far from the beads in it: its box distance is no clearance, and
            # where it would be the smallest so far, the beads say how far it is (at least)
            loose = (dist > touch) & (dist < min(adv.clearance, LOOSE_BELOW_MM)) & ~vertical_covers(covers,
                                                                                                 slice(g0, g1))
            clear = np.where((dist > touch) & ~loose, dist, np.inf)
            if np.isfinite(clear).any():
                g = int(np.argmin(clear))
                adv.bound(float(clear[g]), tool.body.name, int(covers.segment[covers.edges[g0 + g]]))
            at = np.flatnonzero((dist <= touch) | loose)
            near.append(g0 + at)
            box.append(dist[at])
        # those, every tool's a block at a time in path order: the first hit of a body ends its part, and
        # nothing after the earliest hit matters
        best, done = np.inf, set()
        for b0 in range(g0, g1, BLOCK_COVERS):
            if self._covers[0].segment[self._covers[0].edges[b0]] > best:
                break
            for t, (tool, covers) in enumerate(zip(self._tools, self._covers, strict=True)):
                sel = (near[t] >= b0) & (near[t] < b0 + BLOCK_COVERS)
                if t in done or not sel.any():
                    continue
                item = self._body_item(tool.body)
                for k, s0, s1 in narrow(adv, self.trees, segs, tool, item, covers, near[t][sel], box[t][sel], touch):
                    if k > best:
                        break
                    qa, qb = segs.q_at(k, s0), segs.q_at(k, s1)
                    h = adv.refine(item, k, s0, qa, adv.probe(item, k, qa), s1, qb, adv.probe(item, k, qb))
                    if h is not None:
                        hits.append(h)
                        best = min(best, h.segment)
                        done.add(t)
                        break
        return hits

    # --- every item's walk ---------------------------------------------------------------------------

    def _body_item(self, body: Body) -> Item:
        return Item(body.name, body, None, body.rate_mm, body.name == TIP)

    def _work(self, a: int, b: int) -> list[tuple[Item, list[tuple[int, int]]]]:
        """Every item with its runs of batch-local vertices: a body's end at every stretch (what it may
        touch changes), and for a hulled tool cylinder they cover the joint moves only."""
        joint = self.segs.joint[a:b]
        cuts = self._starts[(self._starts > a) & (self._starts < b)] - a
        everywhere = _runs(np.ones(b - a, bool), cuts)
        on_joints = _runs(joint, cuts)
        out = []
        for body in self.bodies.moving:
            out.append((self._body_item(body), on_joints if body.name in self._hulled else everywhere))
        whole = [(0, b - a)]
        for x, y in self.bodies.self_pairs:
            if x.joint < y.joint:                           # named from the far end: "tool_body hits link_4"
                x, y = y, x
            out.append((Item(f"{x.name} <-> {y.name}", x, y, self.bodies.pair_rate_mm(x, y)), whole))
        return out


def _split(tool: ToolCylinder) -> list[ToolCylinder]:
    """A long, slender tool cylinder (the nozzle) as its end near the part (``FOOT_MM`` long) and the rest: the
    covers of a turning tool grow by its half-length times the turn, which the end near the beads is then
    spared."""
    length = 2.0 * tool.half_mm
    if length <= 2.0 * FOOT_MM or tool.radius_mm > FOOT_MM:
        return [tool]
    end = tool.offset_mm + tool.half_mm                         # the end towards the tip (TCP z points out of it)
    foot = ToolCylinder(tool.body, tool.radius_mm, FOOT_MM / 2.0, end - FOOT_MM / 2.0)
    rest = ToolCylinder(tool.body, tool.radius_mm, (length - FOOT_MM) / 2.0, end - FOOT_MM - (length - FOOT_MM) / 2.0)
    return [foot, rest]


def _runs(mask: np.ndarray, cuts: np.ndarray) -> list[tuple[int, int]]:
    """Runs of True segments as (first vertex, last vertex) pairs, also cut at vertices ``cuts``."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    cut = np.zeros(len(mask) + 1, bool)
    cut[cuts] = True
    cut &= np.concatenate([mask, [False]]) & np.concatenate([[False], mask])   # inside a run only
    points = np.sort(np.concatenate([starts, ends, np.flatnonzero(cut), np.flatnonzero(cut)]))
    return [(int(x), int(y)) for x, y in zip(points[0::2], points[1::2], strict=True)]
