"""Bridges: solid infill laid over air, found per layer, with the direction that anchors on both sides.

A layer's solid infill is a *bridge* where nothing of the layer below holds
it up: where the layer's slice overhangs the slice below (an external
bridge, over open air), or where the layer below has sparse infill there
(an internal bridge, over the gaps between sparse lines: PrusaSlicer's
"bridge over infill"). The region found is grown by ``ANCHOR_MM`` into the
rest of the solid infill, so the bridge lines start and end on something.

The direction is chosen as PrusaSlicer's bridge detector does: for every
candidate direction (every 5 degrees, plus the directions of the region's
own edges) lines are laid across the region, and a line counts when both of
its ends rest on the *anchors* (what lies below: the slice below for an
external bridge, the slice below less its sparse infill for an internal
one); the direction with the most anchored length wins, ties going to the
one whose longest unsupported line is shortest. Bridges are printed with the
profile's ``bridge_flow_r`` and ``bridge_speed_mm_s``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from fabric.slicing.builtin.geom import clean, offset
from fabric.slicing.builtin.infill import scan_segments

__all__ = ["Bridge", "find_bridges", "bridge_angle", "ANCHOR_MM"]

ANCHOR_MM = 3.0                 # a bridge region reaches this far into the solid infill around it
_MIN_AREA_BEADS2 = 4.0          # bridges smaller than 4 x 4 bead spacings are plain solid infill
_ANGLE_STEP_DEG = 5.0
_PROBE_SPACINGS = 2.0           # direction probes lay lines two spacings apart


@dataclass
class Bridge:
    """One bridge of a layer: its region and the direction of its lines (rad, in the bed frame)."""

    region: shapely.Geometry
    angle_rad: float


def find_bridges(solid: shapely.Geometry, here: shapely.Geometry, below: shapely.Geometry,
                 sparse_below: shapely.Geometry, spacing_mm: float) -> list[Bridge]:
    """The bridges of a layer whose solid infill is ``solid`` and slice ``here`` (``below``: the layer below)."""
    if solid.is_empty or below.is_empty:
        return []
    min_area = _MIN_AREA_BEADS2 * (4.0 * spacing_mm) ** 2 / 4.0
    over_air = clean(shapely.intersection(solid, shapely.difference(here, below)))
    over_sparse = clean(shapely.intersection(solid, sparse_below)) if not sparse_below.is_empty else shapely.Polygon()
    anchors_air = offset(below, spacing_mm / 2.0)
    anchors_sparse = clean(shapely.difference(below, sparse_below))
    out: list[Bridge] = []
    taken = shapely.Polygon()
    for seed, anchors in ((over_air, anchors_air), (over_sparse, anchors_sparse)):
        if seed.is_empty or seed.area < min_area:
            continue
        # drop slivers (a wall stepping out by less than a bead is not a bridge)
        core = offset(offset(seed, -spacing_mm), spacing_mm)
        if core.is_empty:
            continue
        grown = clean(shapely.intersection(offset(core, ANCHOR_MM), solid))
        grown = clean(shapely.difference(grown, taken)) if not taken.is_empty else grown
        for part in shapely.get_parts(grown):
            if part.is_empty or part.area < min_area:
                continue
            out.append(Bridge(part, bridge_angle(part, anchors, spacing_mm)))
        taken = shapely.union(taken, grown)
    return out


def bridge_angle(region: shapely.Geometry, anchors: shapely.Geometry, spacing_mm: float) -> float:
    """Direction (rad, 0..pi) of the lines that best bridge ``region`` from ``anchors`` to ``anchors``."""
    shapely.prepare(anchors)
    candidates = set(np.round(np.arange(0.0, 180.0, _ANGLE_STEP_DEG), 6).tolist())
    xy = shapely.get_coordinates(shapely.get_exterior_ring(shapely.get_parts(region)))
    if len(xy) > 1:
        d = np.diff(xy, axis=0)
        long = np.hypot(d[:, 0], d[:, 1]) > 2.0 * spacing_mm
        candidates |= set(np.round(np.degrees(np.arctan2(d[long, 1], d[long, 0])) % 180.0, 6).tolist())
    best: tuple[float, float] = (-1.0, 0.0)
    best_angle = 0.0
    for deg in sorted(candidates):
        theta = math.radians(deg)
        seg, _ = scan_segments(region, theta - math.pi / 2.0, _PROBE_SPACINGS * spacing_mm, solid=True)
        if len(seg) == 0:
            continue
        a = seg.to_bed(seg.x, seg.y0)
        b = seg.to_bed(seg.x, seg.y1)
        length = seg.y1 - seg.y0
        held = shapely.contains_xy(anchors, a[:, 0], a[:, 1]) & shapely.contains_xy(anchors, b[:, 0], b[:, 1])
        anchored = float(length[held].sum())
        longest = float(length.max())
        score = (anchored, -longest)
        if score > best:
            best, best_angle = score, theta
    return best_angle
