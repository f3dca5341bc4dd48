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
the tip ``nozzle_clearance_mm`` up; 4 mm x 1 mm on the paper's extruder)
lays the bead under it and rests on the layer below: against the beads of
the layer it is laying and of the layer under it, and only those, it is not
checked. The rest of the nozzle begins where the tip ends, so it clears the
bead being laid by ``nozzle_clearance_mm`` and is checked against
everything. The tip is checked against the plate, the table and every other
bead: printing the first layer it is one layer height above the plate.

How. The path is cut into stretches where the tip's layer changes (and
where that layer's first bead is laid); before each, the beads laid up to
its last row go into the broad phase (:mod:`fabric.collision.trees`). Then,
for the stretch:

1. the nozzle, the tip, and the tool body when it is a cylinder on the same
   axis, along linear moves: swept hulls, all of the stretch in one coal call
   per body (:mod:`fabric.collision.hull`);
2. every other body, those along joint moves, and every pair of robot bodies:
   a vectorised first pass certifies each segment whose bounding-sphere
   distance to the fixed bodies' and the part's bounding boxes (or to the
   other body's sphere) exceeds twice its motion bound;
3. what is left: conservative advancement with exact distances
   (:mod:`fabric.collision.advance`), bisecting where the clearance is small.

Pieces that the first two cannot certify go to the third. The certified
clearance is the smallest lower bound of all; the first hit is the earliest
along the path, and ends the sweep.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from fabric.collision.advance import Advancer, Item, SweepHit
from fabric.collision.beads import BeadSolids
from fabric.collision.bodies import TIP, Body, RobotBodies
from fabric.collision.hull import ToolCylinder, hull_check
from fabric.collision.path import LIVE_ROW, Segments, move_segments, program_segments
from fabric.collision.trees import PartTrees
from fabric.motion.program import Program
from fabric.robot.cell import Cell

__all__ = ["Certifier", "SweepHit", "SweepResult", "TOLERANCE_MM", "exemption_text"]

TOLERANCE_MM = 0.01          # two bodies this close count as touching


def exemption_text(bodies: RobotBodies) -> str:
    """The exemption zone in words, for reports and docs."""
    return (f"{TIP}: r {bodies.tip_radius_mm:g} mm x {bodies.tip_length_mm:g} mm at the nozzle tip, "
            f"exempt against the layer being laid and the one under it")


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
        self.tools = [ToolCylinder(b, r, h, off) for b, r, h, off in self.bodies.axial_cylinders()]
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
                   tip_layer: int = -1, vel_r: float = 0.5, kind: str = "joint") -> SweepResult:
        """Certify one joint move (as the twin times it, at ``vel_r``) against ``beads`` (all laid before)."""
        t0 = time.perf_counter()
        segs = move_segments(self.cell.robot, q_from, q_to, vel_r, kind, tip_layer)
        return self._sweep(segs, beads if beads is not None else BeadSolids.empty(), t0)

    # --- the sweep ------------------------------------------------------------------------------

    def _sweep(self, segs: Segments, beads: BeadSolids, t0: float) -> SweepResult:
        self.segs, self.beads = segs, beads
        self.trees = PartTrees(beads, self.bodies.env)
        self.adv = Advancer(self.bodies, segs, beads, self.trees, self.tol)
        self.pieces = 0
        hit: SweepHit | None = None
        for a, b in segs.runs(self._stretch_keys()):
            last_row = int(segs.row[b - 1])
            count = len(beads) if last_row >= LIVE_ROW else int(np.searchsorted(beads.row, last_row, "left"))
            self.trees.advance(count, int(segs.tip_layer[a]))
            self.adv.set_stretch(a, b)
            hits = self._hulls(a, b) + self.adv.walk(a, b, self._work(a, b))
            if hits:
                hit = min(hits, key=lambda h: (h.segment, h.s))
                break
        adv = self.adv
        return SweepResult(hit is None, adv.clearance, adv.clearance_body, adv.clearance_segment, adv.configs,
                           self.pieces, len(segs), len(beads), hit, time.perf_counter() - t0, segs)

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

    # --- 1. the tool's cylinders along linear moves: swept hulls ---------------------------------

    def _hulls(self, a: int, b: int) -> list[SweepHit]:
        segs, adv = self.segs, self.adv
        idx = a + np.flatnonzero(~segs.joint[a:b])
        checks = [(t, self.trees.coarse_tip if t.body.name == TIP else self.trees.coarse) for t in self.tools]
        hits: list[SweepHit] = []
        for (tool, _), res in zip(checks, hull_check(self.bodies, segs, idx, checks), strict=True):
            self.pieces += res.pieces
            adv.bound(res.clearance_mm, tool.body.name, res.nearest_segment)
            item = self._body_item(tool.body)
            for k, s0, s1 in res.touching:              # in path order: the first hit of this body ends it
                qa, qb = segs.q_at(k, s0), segs.q_at(k, s1)
                h = adv.refine(item, k, s0, qa, adv.probe(item, k, qa), s1, qb, adv.probe(item, k, qb))
                if h is not None:
                    hits.append(h)
                    break
        return hits

    # --- 2. the first pass, 3. conservative advancement -------------------------------------------

    def _body_item(self, body: Body) -> Item:
        return Item(body.name, body, None, body.rate_mm, body.name == TIP)

    def _work(self, a: int, b: int) -> list[tuple[Item, np.ndarray]]:
        """Every item with the segments of [a, b) the first pass leaves to its walk."""
        joint = self.segs.joint[a:b]
        out = []
        for body in self.bodies.moving:
            item = self._body_item(body)
            mask = joint.copy() if body.name in self._hulled else np.ones(b - a, bool)
            out.append((item, mask & ~self._first_pass(item, a, b)))
        for x, y in self.bodies.self_pairs:
            item = Item(f"{x.name} <-> {y.name}", x, y, self.bodies.pair_rate_mm(x, y))
            out.append((item, ~self._first_pass(item, a, b)))
        return out

    def _first_pass(self, item: Item, a: int, b: int) -> np.ndarray:
        """Segments of [a, b) certified by bounding spheres: the body's sphere at the segment's start is
        farther from every obstacle's bounding box (the other body's sphere, for a pair) than twice the
        segment's motion bound. Their clearance is at least half that distance."""
        bodies, adv = self.bodies, self.adv
        frames = adv.frames
        c, r = bodies.spheres(bodies.body_poses(frames, item.body), item.body)
        if item.other is None:
            lo, hi = self.trees.obstacle_boxes()
            gap = np.maximum(np.maximum(lo[None] - c[:, None], c[:, None] - hi[None]), 0.0)
            dist = np.linalg.norm(gap, axis=2).min(axis=1) - r
        else:
            c2, r2 = bodies.spheres(bodies.body_poses(frames, item.other), item.other)
            dist = np.linalg.norm(c - c2, axis=1) - r - r2
        motion = adv.motion(item)
        ok = dist[:-1] > 2.0 * motion + 2.0 * self.tol
        if ok.any():
            lb = dist[:-1] - motion
            i = int(np.argmin(np.where(ok, lb, np.inf)))
            adv.bound(float(lb[i]), item.name, a + i)
        return ok
