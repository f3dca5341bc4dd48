"""Perimeter loops, infill areas and the solid / sparse split of every layer.

Perimeters are inward offsets of each island (a polygon with its holes): the
external loop's centreline sits half a bead width inside the outline, each
further loop one bead *spacing* further in (mitred joins, limit 3, like
Clipper in PrusaSlicer). The infill area is what remains inside the last
loop, less half a spacing, plus the configured overlap with the perimeters;
an opening of 0.6 spacing drops slivers too narrow for a bead.

Gaps follow PrusaSlicer's classic perimeter generator: after each inner
loop (and one more trial loop past the last) the band between the previous
region shrunk by half a step and the new one grown by half a step is a
*gap*, somewhere the next loop did not fit; its parts between a fifth of a
bead and two spacings wide are printed as gap fill (:mod:`.gapfill`) and
kept out of the infill. When a loop, or the trial loop, does not fit at
all, the island has no infill: what is left is at most gap fill. Each
island also carries its *travel region* (:mod:`.travel`): the outline
shrunk to just outside its external perimeter.

Solid layers (PrusaSlicer's horizontal shells): a layer's *top shell* is the
part of its slice with no material in the layer above (slivers of sloped
walls dropped), plus its own exposed infill grown by ``EXTERNAL_MARGIN_MM``
so the skin is anchored over the sparse infill around it; it makes the
``top_solid_layers`` layers down to it solid wherever their infill area lies
under it. Bottom shells work the same way upwards (the first layer is all
bottom). Thin crescents of shell are widened so they print as a skin rather
than a line or two. What is left of the infill area is sparse infill.
"""
from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass, field

import numpy as np
import shapely

from fabric.slicing.builtin.gapfill import GapPath, gap_fill_paths
from fabric.slicing.builtin.geom import clean, offset
from fabric.slicing.builtin.travel import INSIDE_MARGIN_MM
from fabric.slicing.flow import bead_spacing_mm

__all__ = ["Loop", "Island", "FillSplit", "island_perimeters", "classify_fill", "offset", "clean",
           "EXTERNAL_MARGIN_MM"]

EXTERNAL_MARGIN_MM = 3.0
_OPENING_R = 0.6            # drop infill areas narrower than 0.6 bead spacing
_NARROW_BEADS = 3.0         # solid shells narrower than 2 x this many beads get widened
_GAP_SAFETY_MM = 1e-5       # PrusaSlicer's 10 scaled units of safety offset
_GAP_MIN_R = 0.2 * (1.0 - 0.4)      # narrowest gap filled: a fifth of a bead less the inset overlap tolerance


@dataclass
class Loop:
    """One perimeter loop: closed centreline (n, 2) without the repeated end, its depth (0 = external)."""

    xy: np.ndarray
    depth: int
    hole: bool
    notch: np.ndarray | None = field(default=None, repr=False, compare=False)   # seam bonus weights, once


@dataclass
class Island:
    """One connected part of a layer: its outline, perimeter loops and infill area."""

    outline: shapely.Geometry
    loops: list[Loop] = field(default_factory=list)
    fill: shapely.Geometry = field(default_factory=shapely.Polygon)
    gaps: list[GapPath] = field(default_factory=list)
    travel: shapely.Geometry = field(default_factory=shapely.Polygon)


def _rings(geom: shapely.Geometry, depth: int) -> list[Loop]:
    """Exterior (CCW) and hole (CW) rings of a (multi)polygon as loops."""
    out = []
    for part in shapely.get_parts(geom):
        if part.is_empty:
            continue
        part = shapely.orient_polygons(part) if hasattr(shapely, "orient_polygons") else \
            shapely.geometry.polygon.orient(part, 1.0)
        out.append(Loop(np.asarray(part.exterior.coords)[:-1, :2], depth, False))
        out.extend(Loop(np.asarray(r.coords)[:-1, :2], depth, True) for r in part.interiors)
    return out


def island_perimeters(outline: shapely.Geometry, perimeters: int, width_mm: float, height_mm: float,
                      overlap_r: float, gap_fill: bool = True) -> Island:
    """Loops, gap fill and infill area of one island at a layer of ``height_mm``."""
    spacing = bead_spacing_mm(width_mm, height_mm)
    island = Island(outline)
    island.travel = clean(offset(outline, -(width_mm / 2.0 - INSIDE_MARGIN_MM)))
    last = outline
    gaps: list[shapely.Geometry] = []
    if perimeters > 0:
        for k in range(perimeters + 1):             # pass ``perimeters`` is the trial loop
            if k == perimeters and not gap_fill:
                break
            step = width_mm / 2.0 if k == 0 else spacing
            nxt = offset(last, -step)
            if k > 0 and gap_fill:
                gap = shapely.difference(offset(last, -step / 2.0), offset(nxt, step / 2.0 + _GAP_SAFETY_MM))
                if not gap.is_empty:
                    gaps.append(gap)
            if nxt.is_empty:
                last = shapely.Polygon()            # no room for this loop: no infill either
                break
            if k == perimeters:
                break
            island.loops.extend(_rings(nxt, k))
            last = nxt
        if not island.loops:
            return island
        if gaps:
            island.gaps, covered = gap_fill_paths(clean(shapely.union_all(gaps)), _GAP_MIN_R * width_mm,
                                                  2.0 * spacing, height_mm)
            if island.gaps and not last.is_empty:
                last = shapely.difference(last, covered)
        if last.is_empty:
            return island
        # fill boundary: half a spacing inside the last loop, minus the overlap.
        inset = spacing / 2.0 - overlap_r * spacing
    else:
        inset = 0.0
    opening = _OPENING_R * spacing / 2.0
    inner = offset(clean(last), -(inset + opening))
    island.fill = clean(offset(inner, opening)) if not inner.is_empty else inner
    return island


@dataclass
class FillSplit:
    """A layer's infill area split into solid (with its top-surface part) and sparse."""

    solid: shapely.Geometry
    top: shapely.Geometry
    sparse: shapely.Geometry


def classify_fill(fills: list[shapely.Geometry], slices: list[shapely.Geometry], keys: list[bytes],
                  top_layers: int, bottom_layers: int, density_r: float, bead_mm: float,
                  pool: Executor | None = None) -> list[FillSplit]:
    """Split every layer's infill area into solid and sparse (see module docstring).

    A layer's *shell* towards the top is the area of its slice not covered by
    the layer above (slivers narrower than a fifth of a bead dropped), plus
    its own top infill surface grown by the external margin; it makes the
    ``top_layers`` layers down to it solid where their infill area lies
    under it (the bottom shell likewise, upwards). Because the shell includes
    the perimeter band, a gently sloped surface gets its skin even when each
    layer only steps out by less than a perimeter width. Solid parts
    narrower than six beads are widened by three beads into the sparse area,
    so they do not collapse. ``keys`` identify equal slices: between equal
    slices there is no shell, which skips most boolean operations on
    prismatic parts. Layers are independent here, so ``pool`` (threads:
    GEOS releases the GIL) may run them in parallel.
    """
    n = len(fills)
    empty = shapely.Polygon()
    sliver = bead_mm / 10.0
    run = pool.map if pool is not None else map

    def shells_of(i: int) -> tuple[shapely.Geometry, shapely.Geometry, shapely.Geometry]:
        up = down = own_top = empty
        if slices[i].is_empty:
            return up, down, own_top
        if top_layers > 0:
            if i == n - 1 or slices[i + 1].is_empty:
                up, own_top = slices[i], fills[i]
            elif keys[i + 1] != keys[i]:
                up, own_top = _shell(slices[i], slices[i + 1], fills[i], sliver)
        if bottom_layers > 0:
            if i == 0 or slices[i - 1].is_empty:
                down = slices[i]
            elif keys[i - 1] != keys[i]:
                down, _ = _shell(slices[i], slices[i - 1], fills[i], sliver)
        return up, down, own_top

    ups, downs, own_tops = (list(t) for t in zip(*run(shells_of, range(n)), strict=True)) if n else ([], [], [])

    def split_of(i: int) -> FillSplit:
        f = fills[i]
        if f.is_empty:
            return FillSplit(empty, empty, empty)
        if density_r >= 1.0:
            return FillSplit(f, own_tops[i], empty)
        shells = [g for g in ups[i:i + top_layers] + downs[max(0, i - bottom_layers + 1):i + 1]
                  if not g.is_empty]
        if not shells:
            solid = empty
        elif any(g is slices[i] for g in shells):
            solid = f
        elif density_r > 0:
            solid = _widen_narrow(clean(_clip_union(f, shells)), f, bead_mm)
        else:
            # hollow print: a shell thinner than two beads only crosses a sloped wall; drop it
            solid = clean(_clip_union(f, shells))
            solid = shapely.intersection(solid, offset(offset(solid, -bead_mm), bead_mm))
        sparse = f if solid.is_empty else clean(shapely.difference(f, solid))
        top = own_tops[i]
        if not (top.is_empty or solid is f):
            top = clean(shapely.intersection(top, solid))
        return FillSplit(solid, top, sparse if density_r > 0 else empty)

    return list(run(split_of, range(n)))


def _clip_union(f: shapely.Geometry, shells: list[shapely.Geometry]) -> shapely.Geometry:
    """``f`` intersected with the union of ``shells``: clip each first (cheap), then unite the pieces."""
    fb = shapely.bounds(f)
    pieces = []
    for g in shells:
        gb = shapely.bounds(g)
        if gb[0] > fb[2] or gb[2] < fb[0] or gb[1] > fb[3] or gb[3] < fb[1]:
            continue
        piece = shapely.intersection(f, g)
        if not piece.is_empty and piece.area > 1e-9:
            pieces.append(piece)
    if not pieces:
        return shapely.Polygon()
    return pieces[0] if len(pieces) == 1 else shapely.union_all(pieces)


def _shell(here: shapely.Geometry, other: shapely.Geometry, fill: shapely.Geometry,
           sliver_mm: float) -> tuple[shapely.Geometry, shapely.Geometry]:
    """(shell, own skin) of a layer facing a neighbour layer (above or below)."""
    empty = shapely.Polygon()
    exposed = shapely.difference(here, other)
    if exposed.is_empty or exposed.area < 1e-6:
        return empty, empty
    core = offset(clean(exposed), -sliver_mm)
    if core.is_empty:
        return empty, empty
    exposed = offset(core, sliver_mm)
    skin = shapely.intersection(fill, exposed)
    if skin.is_empty or skin.area < 1e-6:
        return exposed, empty
    skin = clean(shapely.intersection(offset(skin, EXTERNAL_MARGIN_MM), fill))
    return clean(shapely.union(exposed, skin)), skin


def _widen_narrow(solid: shapely.Geometry, fill: shapely.Geometry, bead_mm: float) -> shapely.Geometry:
    """Grow the parts of ``solid`` narrower than six beads by three beads, inside ``fill``.

    A sloped surface's shell projected onto a lower layer is often a thin
    crescent that would print as a line or two; widening it (as PrusaSlicer
    does) gives the skin above something to rest on.
    """
    if solid.is_empty:
        return solid
    margin = _NARROW_BEADS * bead_mm
    opened = offset(offset(solid, -margin), margin)
    narrow = shapely.difference(solid, opened)
    if narrow.is_empty or narrow.area < 1e-6:
        return solid
    grown = shapely.intersection(offset(narrow, margin), fill)
    return clean(shapely.union(solid, grown))
