"""Line infill (rectilinear, grid) by a vectorised scan-line, and its boustrophedon ordering.

The region is rotated so the infill lines are vertical (``x = k * spacing``
on a grid fixed to the bed, so sparse lines stack from layer to layer). Every
polygon edge spanning a line ``x = k s`` (half-open, so a line through a
vertex counts once) gives one crossing; sorted by ``(k, y)`` the crossings of
each line pair up inside / outside (even-odd rule) into segments. No shapely
clipping of individual lines is needed.

Solid infill uses the PrusaSlicer arrangement: spacing stretched (at most
20 %) so a whole number of lines fits the region's width, lines half a
spacing in from its edges, and consecutive lines joined by short extruded
links into zig-zags. Sparse infill lines are spaced ``spacing / density``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from fabric.slicing.builtin.geom import ring_walk

__all__ = ["Rings", "Segments", "scan_segments", "adjust_solid_spacing", "extend_to", "chain_segments"]


@dataclass
class Rings:
    """The boundary rings the segments were cut from: vertices (bed frame) and arc length per vertex."""

    xy: np.ndarray          # (n, 2) vertices, each ring closed (last == first)
    pos: np.ndarray         # arc length of each vertex from its ring's start
    start: np.ndarray       # index of each ring's first vertex (+ closing entry)
    length: np.ndarray      # perimeter of each ring


@dataclass
class Segments:
    """Infill segments in the rotated frame: line index ``k``, ``x`` and the ``y0 < y1`` span.

    Each end also records the boundary ring it lies on (``r0``/``r1``) and its
    arc-length position along it (``s0``/``s1``), so links can follow the boundary.
    """

    k: np.ndarray
    x: np.ndarray
    y0: np.ndarray
    y1: np.ndarray
    r0: np.ndarray
    s0: np.ndarray
    r1: np.ndarray
    s1: np.ndarray
    angle_rad: float
    rings: Rings | None = None
    e0: np.ndarray | None = None        # where a free (unlinked) end may extend to
    e1: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.e0 is None:
            self.e0 = self.y0
        if self.e1 is None:
            self.e1 = self.y1

    def __len__(self) -> int:
        return len(self.k)

    def ends(self) -> tuple[np.ndarray, np.ndarray]:
        """Where the free ends may extend to (``e0``, ``e1``; set from ``y0``, ``y1`` on construction)."""
        return (self.y0 if self.e0 is None else self.e0), (self.y1 if self.e1 is None else self.e1)

    def take(self, mask: np.ndarray) -> Segments:
        """The segments selected by a boolean mask (or index array)."""
        e0, e1 = self.ends()
        return Segments(self.k[mask], self.x[mask], self.y0[mask], self.y1[mask], self.r0[mask],
                        self.s0[mask], self.r1[mask], self.s1[mask], self.angle_rad, self.rings,
                        e0[mask], e1[mask])

    def to_bed(self, xr: np.ndarray, yr: np.ndarray) -> np.ndarray:
        """Rotate rotated-frame points back to bed coordinates, (n, 2)."""
        c, s = math.cos(self.angle_rad), math.sin(self.angle_rad)
        return np.column_stack([c * xr - s * yr, s * xr + c * yr])


def _empty(angle_rad: float) -> Segments:
    z = np.zeros(0)
    zi = np.zeros(0, dtype=np.int64)
    return Segments(zi, z, z, z, zi, z, zi, z, angle_rad)


def adjust_solid_spacing(width_mm: float, spacing_mm: float) -> float:
    """Stretch ``spacing_mm`` so a whole number of intervals spans ``width_mm`` (at most +20 %)."""
    n = int((width_mm - 1e-9) // spacing_mm)
    if n <= 0:
        return spacing_mm
    return min(width_mm / n, spacing_mm * 1.2)


def _rotated_x_range(geom: shapely.Geometry, c: float, s: float) -> tuple[float, float]:
    xy = shapely.get_coordinates(geom)
    xr = c * xy[:, 0] + s * xy[:, 1]
    return float(xr.min()), float(xr.max())


def scan_segments(region: shapely.Geometry, angle_rad: float, spacing_mm: float, *, solid: bool,
                  frame: shapely.Geometry | None = None, grid_origin_xy: tuple[float, float] = (0.0, 0.0),
                  margin_mm: float = 0.0) -> tuple[Segments, float]:
    """Infill segments of ``region`` at ``angle_rad`` and their (possibly stretched) spacing.

    ``frame`` is the unclipped infill area the lines are laid out in (the
    region itself when None). For ``solid``, the spacing is stretched to fit
    the frame's width and the first line sits half a spacing inside it;
    otherwise lines sit on the grid ``x = x0 + k * spacing`` through
    ``grid_origin_xy`` (so sparse lines stack from layer to layer), and lines
    closer than ``margin_mm`` to the frame's extreme x are left out.
    """
    if region.is_empty:
        return _empty(angle_rad), spacing_mm
    rings = shapely.get_rings(shapely.get_parts(region))
    xy, ring_of = shapely.get_coordinates(rings, return_index=True)
    if len(xy) < 4:
        return _empty(angle_rad), spacing_mm
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    rot = np.column_stack([c * xy[:, 0] + s * xy[:, 1], -s * xy[:, 0] + c * xy[:, 1]])
    same = ring_of[1:] == ring_of[:-1]          # consecutive points of one (closed) ring
    edge_len = np.where(same, np.linalg.norm(np.diff(xy, axis=0), axis=1), 0.0)
    pos = np.r_[0.0, np.cumsum(edge_len)]
    ring_start = np.r_[0, np.flatnonzero(~same) + 1, len(xy)]
    pos -= np.repeat(pos[ring_start[:-1]], np.diff(ring_start))
    ring_len = pos[ring_start[1:] - 1]
    edges = np.flatnonzero(same)
    a, b = rot[edges], rot[edges + 1]
    xmin, xmax = _rotated_x_range(frame, c, s) if frame is not None else (rot[:, 0].min(), rot[:, 0].max())
    if solid:
        spacing_mm = adjust_solid_spacing(xmax - xmin, spacing_mm)
        origin = xmin + spacing_mm / 2.0
    else:
        origin = c * grid_origin_xy[0] + s * grid_origin_xy[1]
    lo = np.minimum(a[:, 0], b[:, 0])
    hi = np.maximum(a[:, 0], b[:, 0])
    k_first = np.ceil((lo - origin) / spacing_mm).astype(np.int64)
    k_last = np.ceil((hi - origin) / spacing_mm).astype(np.int64) - 1     # k s < hi
    count = np.maximum(k_last - k_first + 1, 0)
    total = int(count.sum())
    if total == 0:
        return _empty(angle_rad), spacing_mm
    e = np.repeat(np.arange(len(a)), count)
    k = k_first[e] + (np.arange(total) - np.repeat(np.cumsum(count) - count, count))
    x = origin + k * spacing_mm
    ea, eb = a[e], b[e]
    t = (x - ea[:, 0]) / (eb[:, 0] - ea[:, 0])
    y = ea[:, 1] + t * (eb[:, 1] - ea[:, 1])
    ring = ring_of[edges[e]]
    arc = pos[edges[e]] + t * edge_len[edges[e]]
    order = np.lexsort((y, k))
    k, x, y, ring, arc = k[order], x[order], y[order], ring[order], arc[order]
    # each line must have an even number of crossings; drop lines that do not (numerical trouble)
    starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
    counts = np.diff(np.r_[starts, len(k)])
    good = np.repeat(counts % 2 == 0, counts)
    k, x, y, ring, arc = k[good], x[good], y[good], ring[good], arc[good]
    seg = Segments(k[0::2], x[0::2], y[0::2], y[1::2], ring[0::2], arc[0::2], ring[1::2], arc[1::2],
                   angle_rad, Rings(xy, pos, ring_start, ring_len))
    keep = seg.y1 - seg.y0 > 1e-3
    if margin_mm > 0:
        keep &= (seg.x >= xmin + margin_mm) & (seg.x <= xmax - margin_mm)
    return seg.take(keep), spacing_mm


def extend_to(inner: Segments, outer: Segments) -> Segments:
    """Inner segments that lie within some outer segment, with free ends reaching the outer one.

    ``inner`` are cut from the region shrunk by half a spacing, ``outer``
    from the region shrunk by a twentieth: a line is printed only where it
    reaches the inner region, and where a chain starts or ends (no link
    there) its end extends to the outer crossing, as in PrusaSlicer. When
    several inner pieces share one outer segment (the inner region pinches),
    only the first and last extend.
    """
    if len(inner) == 0 or len(outer) == 0:
        return inner.take(np.zeros(len(inner), dtype=bool))
    key_o = outer.k.astype(np.float64) * 1e7 + outer.y0
    mid = (inner.y0 + inner.y1) / 2.0
    j = np.searchsorted(key_o, inner.k.astype(np.float64) * 1e7 + mid, side="right") - 1
    jj = np.maximum(j, 0)
    ok = (j >= 0) & (outer.k[jj] == inner.k) & (outer.y1[jj] >= mid)
    out = inner.take(ok)
    j = j[ok]
    first = np.r_[True, j[1:] != j[:-1]]
    last = np.r_[j[1:] != j[:-1], True]
    out.e0 = np.where(first, outer.y0[j], out.y0)
    out.e1 = np.where(last, outer.y1[j], out.y1)
    return out


def chain_segments(seg: Segments, start_bed: tuple[float, float], link_max_mm: float) -> list[np.ndarray]:
    """Order segments as boustrophedon chains; returns polylines in bed coordinates.

    From the unvisited segment end nearest the current position, a chain
    walks to the next scan line, taking the overlapping unvisited segment
    whose near end is closest, reversing direction on each line. With
    ``link_max_mm > 0`` (solid infill) consecutive segments of a chain are
    joined into one polyline by the shorter way along the boundary ring both
    ends lie on, when that is at most ``link_max_mm``; otherwise each segment
    is its own polyline (a travel separates them) but the order is kept.
    """
    n = len(seg)
    if n == 0:
        return []
    order, flipped, chain_id = _boustrophedon(seg, start_bed)
    idx = np.asarray(order)
    ya = np.where(flipped, seg.y1[idx], seg.y0[idx])
    yb = np.where(flipped, seg.y0[idx], seg.y1[idx])
    e0, e1 = seg.ends()
    xa = np.where(flipped, e1[idx], e0[idx])        # extended ends
    xb = np.where(flipped, e0[idx], e1[idx])
    if link_max_mm <= 0 or seg.rings is None:
        return list(np.stack([seg.to_bed(seg.x[idx], xa), seg.to_bed(seg.x[idx], xb)], axis=1))
    ra = np.where(flipped, seg.r1[idx], seg.r0[idx])
    sa = np.where(flipped, seg.s1[idx], seg.s0[idx])
    rb = np.where(flipped, seg.r0[idx], seg.r1[idx])
    sb = np.where(flipped, seg.s0[idx], seg.s1[idx])
    rings = seg.rings
    length = rings.length
    fwd = np.zeros(len(idx))
    same = np.zeros(len(idx), dtype=bool)
    same[1:] = (ra[1:] == rb[:-1]) & (chain_id[1:] == chain_id[:-1])
    if same.any():
        L = length[ra[1:]]
        fwd[1:] = np.mod(sa[1:] - sb[:-1], L)
        short = np.minimum(fwd[1:], L - fwd[1:])
        same[1:] &= short <= link_max_mm
    # ends with no link reach out to the outer crossing
    joined_after = np.r_[same[1:], False]
    ya = np.where(same, ya, xa)
    yb = np.where(joined_after, yb, xb)
    lines = np.stack([seg.to_bed(seg.x[idx], ya), seg.to_bed(seg.x[idx], yb)], axis=1)   # (n, 2, 2)
    out: list[np.ndarray] = []
    current = [lines[0]]
    for m in range(1, len(idx)):
        if same[m]:
            current.append(_ring_path(rings, int(ra[m]), float(sb[m - 1]), float(sa[m]), float(fwd[m])))
            current.append(lines[m])
        else:
            out.append(np.concatenate(current) if len(current) > 1 else current[0])
            current = [lines[m]]
    out.append(np.concatenate(current) if len(current) > 1 else current[0])
    return out


def _ring_path(rings: Rings, r: int, s_from: float, s_to: float, fwd: float) -> np.ndarray:
    """Ring vertices strictly between arc positions ``s_from`` and ``s_to``, the shorter way round."""
    lo, hi = int(rings.start[r]), int(rings.start[r + 1]) - 1      # hi: the closing duplicate
    return ring_walk(rings.pos[lo:hi], rings.xy[lo:hi], float(rings.length[r]), s_from, s_to, fwd)


def _boustrophedon(seg: Segments, start_bed: tuple[float, float]) -> tuple[list[int], np.ndarray, np.ndarray]:
    """Visit order of the segments, whether each is walked y1 -> y0, and its chain number."""
    n = len(seg)
    c, s = math.cos(seg.angle_rad), math.sin(seg.angle_rad)
    px = c * start_bed[0] + s * start_bed[1]
    py = -s * start_bed[0] + c * start_bed[1]
    uniq, first, cnt = np.unique(seg.k, return_index=True, return_counts=True)
    line_start = dict(zip(uniq.tolist(), first.tolist(), strict=True))
    line_end = dict(zip(uniq.tolist(), (first + cnt).tolist(), strict=True))
    visited = np.zeros(n, dtype=bool)
    ends_x = np.concatenate([seg.x, seg.x])
    ends_y = np.concatenate([seg.y0, seg.y1])
    x_l, y0_l, y1_l, k_l = seg.x.tolist(), seg.y0.tolist(), seg.y1.tolist(), seg.k.tolist()
    seen = [False] * n
    order: list[int] = []
    flip: list[bool] = []
    chain_id: list[int] = []
    chains = 0
    remaining = n
    while remaining:
        d = (ends_x - px) ** 2 + (ends_y - py) ** 2
        d[np.concatenate([visited, visited])] = np.inf
        j = int(np.argmin(d))
        i, up = (j, True) if j < n else (j - n, False)     # up: enter at y0, leave at y1
        step = 0
        while True:
            visited[i] = True
            seen[i] = True
            remaining -= 1
            order.append(i)
            flip.append(not up)
            chain_id.append(chains)
            end_y = y1_l[i] if up else y0_l[i]
            nxt = -1
            for direction in ((step,) if step else (1, -1)):
                kk = k_l[i] + direction
                if kk not in line_start:
                    continue
                best = math.inf
                for cand in range(line_start[kk], line_end[kk]):
                    if seen[cand] or y1_l[cand] < y0_l[i] or y0_l[cand] > y1_l[i]:
                        continue
                    dist = abs((y1_l[cand] if up else y0_l[cand]) - end_y)
                    if dist < best:
                        best, nxt = dist, cand
                if nxt >= 0:
                    step = direction
                    break
            if nxt < 0:
                break
            i, up = nxt, not up
        px, py = x_l[i], end_y
        chains += 1
    return order, np.asarray(flip), np.asarray(chain_id)
