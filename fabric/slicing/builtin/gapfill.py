"""Gap fill: one bead of varying width along the middle of each region too thin for a perimeter loop.

A gap is a narrow band left between perimeters (see :mod:`.regions`). It is
printed along its *medial axis*, the centre line of the band: the Voronoi
diagram of points spaced along the band's boundary (built from their
Delaunay triangulation) has, inside a thin band, edges that run between the
points of opposite sides, i.e. along its middle (edges between neighbours on
one side point out of the band and are dropped). Where the axis lies at distance ``r`` from the boundary the band
is ``2 r`` thick, and the bead laid there is as wide as makes its *spacing*
equal to that thickness (``w = 2 r + h (1 - pi / 4)``), so the bead fills
the band's cross-section exactly, as PrusaSlicer's variable-width gap fill
does. Bands thinner than ``min_mm`` are left empty and parts of the axis
where the band is thicker than ``max_mm`` (they have a loop or infill)
are left out.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from scipy.spatial import Delaunay, KDTree

from fabric.slicing.builtin.geom import clean, offset

__all__ = ["GapPath", "gap_fill_paths"]

_STEP_R = 1.0           # boundary points about one band thickness apart
_MIN_STEP_MM = 0.04
_MIN_LENGTH_R = 1.0     # axis pieces shorter than one bead width are dropped (corner spurs)


@dataclass
class GapPath:
    """One gap-fill bead: its polyline (m, 2) and each segment's bead width (m - 1)."""

    xy: np.ndarray
    widths_mm: np.ndarray


def gap_fill_paths(gaps: shapely.Geometry, min_mm: float, max_mm: float,
                   height_mm: float) -> tuple[list[GapPath], shapely.Geometry]:
    """Beads filling the parts of ``gaps`` between ``min_mm`` and ``max_mm`` thick (PrusaSlicer's rule).

    Returns the beads and the area they cover (to keep out of the infill).
    All bands of one island go through one Voronoi diagram.
    """
    empty = shapely.Polygon()
    if gaps.is_empty:
        return [], empty
    opened = offset(offset(gaps, -min_mm / 2.0), min_mm / 2.0)
    wide = offset(offset(gaps, -max_mm / 2.0), max_mm / 2.0 + 1e-5)
    bands = clean(shapely.difference(opened, wide)) if not wide.is_empty else opened
    parts = [b for b in shapely.get_parts(bands) if not b.is_empty and b.area >= min_mm * min_mm]
    if not parts:
        return [], empty
    bands = parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)
    extra = height_mm * (1.0 - math.pi / 4.0)           # bead width minus its spacing
    out = []
    for xy, thick in _medial_axis(bands, min_mm, max_mm):
        seg_thick = np.minimum((thick[1:] + thick[:-1]) / 2.0, max_mm)
        out.append(GapPath(xy, seg_thick + extra))
    return out, (shapely.buffer(bands, extra / 2.0) if out else empty)


def _medial_axis(band: shapely.Geometry, min_mm: float, max_mm: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Polylines along the middle of ``band`` (one or more polygons) and its thickness at each of their vertices."""
    parts = shapely.get_parts(band)
    mean_thick = 2.0 * shapely.area(parts) / np.maximum(shapely.length(parts), 1e-9)   # perimeter ~ 2 x length
    step = np.clip(_STEP_R * mean_thick, _MIN_STEP_MM, max_mm / 2.0)
    coords, ring_of = shapely.get_coordinates(shapely.get_rings(shapely.segmentize(parts, step)), return_index=True)
    closing = np.r_[np.diff(ring_of) != 0, True]            # each ring's repeated first point
    pts, ring_of = coords[~closing], ring_of[~closing]
    if len(pts) < 4:
        return []
    first = np.r_[0, np.flatnonzero(np.diff(ring_of)) + 1]
    after = np.arange(1, len(pts) + 1)                      # the next sample along the same ring, cyclic
    after[np.r_[first[1:], len(pts)] - 1] = first
    # Voronoi edges from the Delaunay triangulation: a triangle's circumcentre is a Voronoi vertex, and
    # the circumcentres of two triangles sharing a side are joined by a Voronoi edge
    tri = Delaunay(pts)
    corners = pts[tri.simplices]                            # (t, 3, 2)
    centre = _circumcentres(corners)
    shapely.prepare(band)
    ok = np.isfinite(centre).all(axis=1)
    ok[ok] = shapely.contains_xy(band, centre[ok, 0], centre[ok, 1])
    t_idx, side = np.nonzero(tri.neighbors >= 0)
    n_idx = tri.neighbors[t_idx, side]
    pair = (t_idx < n_idx) & ok[t_idx] & ok[n_idx]
    a, b = centre[t_idx[pair]], centre[n_idx[pair]]
    mid = (a + b) / 2.0
    inside = shapely.contains_xy(band, mid[:, 0], mid[:, 1])
    if not inside.any():
        return []
    edges = shapely.linestrings(np.stack([a[inside], b[inside]], axis=1))
    lines = shapely.get_parts(shapely.line_merge(shapely.multilinestrings(edges)))
    lines = lines[shapely.length(lines) >= min_mm + _MIN_LENGTH_R * min_mm]     # corner spurs, early
    if len(lines) == 0:
        return []
    coords, which = shapely.get_coordinates(lines, return_index=True)
    thick_all = 2.0 * _boundary_distance(coords, pts, after)
    splits = np.flatnonzero(np.diff(which)) + 1
    out = []
    for xy, thick in zip(np.split(coords, splits), np.split(thick_all, splits), strict=True):
        keep = thick >= min_mm
        if not keep.all():                    # cut where the band is too thin: keep the longest run
            runs = np.split(np.arange(len(xy)), np.flatnonzero(np.diff(keep.astype(int)) != 0) + 1)
            runs = [r for r in runs if keep[r[0]] and len(r) >= 2]
            if not runs:
                continue
            best = max(runs, key=len)
            xy, thick = xy[best], thick[best]
        length = float(np.hypot(*np.diff(xy, axis=0).T).sum())
        if length < _MIN_LENGTH_R * float(np.mean(thick)) + min_mm or thick.max() > max_mm * 1.5:
            continue
        out.append((xy, thick))
    return _extend_ends(out, band.boundary)


def _circumcentres(tri: np.ndarray) -> np.ndarray:
    """Circumcentre of each triangle (t, 3, 2); NaN for a degenerate (flat) one."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac = b - a, c - a
    d = 2.0 * (ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])
    ab2, ac2 = (ab * ab).sum(axis=1), (ac * ac).sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (ac[:, 1] * ab2 - ab[:, 1] * ac2) / d
        uy = (ab[:, 0] * ac2 - ac[:, 0] * ab2) / d
    out = a + np.column_stack([ux, uy])
    out[np.abs(d) < 1e-15] = np.nan
    return out


def _boundary_distance(q: np.ndarray, pts: np.ndarray, after: np.ndarray) -> np.ndarray:
    """Distance from each point of ``q`` to the boundary sampled as ``pts`` (``after``: next sample on its ring).

    The nearest sample's two boundary segments hold the nearest boundary point
    (the samples are denser than the band is thick), so this is exact there
    without measuring against the whole boundary.
    """
    k = KDTree(pts).query(q)[1]
    before = np.empty_like(after)
    before[after] = np.arange(len(after))
    best = np.full(len(q), np.inf)
    for a_idx, b_idx in ((k, after[k]), (before[k], k)):
        a, b = pts[a_idx], pts[b_idx]
        ab = b - a
        t = np.clip(((q - a) * ab).sum(axis=1) / np.maximum((ab * ab).sum(axis=1), 1e-18), 0.0, 1.0)
        best = np.minimum(best, np.hypot(*(q - a - t[:, None] * ab).T))
    return best


def _extend_ends(axes: list[tuple[np.ndarray, np.ndarray]],
                 boundary: shapely.Geometry) -> list[tuple[np.ndarray, np.ndarray]]:
    """Carry each end of every axis on in its direction to the band's edge (an axis stops half a width short).

    An end that meets the edge within its own thickness is moved there, keeping its width, as
    PrusaSlicer extends the medial axis; an end at a junction or in a wide spot stays. All ends are
    cast against the edge in one call.
    """
    if not axes:
        return []
    end = np.asarray([p for xy, _ in axes for p in (xy[0], xy[-1])])
    prev = np.asarray([p for xy, _ in axes for p in (xy[1], xy[-2])])
    reach = np.asarray([w for _, t in axes for w in (t[0], t[-1])])
    d = end - prev
    n = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
    rays = shapely.linestrings(np.stack([end, end + d / n[:, None] * reach[:, None]], axis=1))
    hits = shapely.intersection(rays, boundary)
    out = []
    for k, (xy, thick) in enumerate(axes):
        parts = [xy]
        widths = [thick]
        for j, at_start in ((2 * k, True), (2 * k + 1, False)):
            if hits[j].is_empty:
                continue
            cand = shapely.get_coordinates(hits[j])
            far = cand[int(np.argmin(np.hypot(*(cand - end[j]).T)))][None]
            parts.insert(0 if at_start else len(parts), far)
            widths.insert(0 if at_start else len(widths), reach[j:j + 1])
        out.append((np.concatenate(parts), np.concatenate(widths)))
    return out
