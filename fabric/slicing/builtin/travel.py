"""Travel planning: routes that stay inside the part, and whether a travel must retract.

Every layer has a *travel region*: each island's outline shrunk to just
outside its external perimeter's centreline (:data:`INSIDE_MARGIN_MM` short
of it), so a move inside it passes over the part, never over open air. Where
a wall is too thin for that region to get through (it breaks into pieces at
a neck), the island's outline itself (less :data:`OUTLINE_MARGIN_MM`) is the
fallback region: a move there still passes over the part. A travel between
two points of the same connected piece of a region is routed inside it,
PrusaSlicer's "avoid crossing perimeters": where the straight move leaves
the region (across a hole, or across a notch of the outline) it is replaced
by a walk along the boundary ring it crossed, the shorter way round from the
exit point to the re-entry point. The walk is thinned by Douglas-Peucker to
within ``_THIN_MM`` of the edge it follows, then pulled tight by dropping,
pass after pass, every corner whose neighbours see each other inside the
region (a walk with more than ``_TIGHTEN_MAX_POINTS`` corners left is kept as
thinned). Such a travel does not retract (any ooze lands on the part, inside
its walls) unless the route is longer than the profile's
``retract_inside_max_mm``. A travel that starts or ends outside the region
(the skirt, another island) crosses a perimeter into open air: it goes
straight, and retracts when it is longer than ``retract_min_travel_mm``, as
every travel did before.
"""
from __future__ import annotations

import math

import numpy as np
import shapely

from fabric.slicing.builtin.geom import ring_walk

__all__ = ["TravelPlanner", "TravelPiece", "travel_pieces", "INSIDE_MARGIN_MM", "OUTLINE_MARGIN_MM"]

INSIDE_MARGIN_MM = 0.05     # the region's edge lies this far outside the external perimeter's centreline
OUTLINE_MARGIN_MM = 0.01    # the fallback region's edge lies this far inside the outline
_EPS = 1e-9
_TIGHTEN_MAX_POINTS = 48    # walks with more corners than this are thinned, and pulled tight only when few are left
_TIGHTEN_PASSES = 4
_THIN_MM = 0.04             # how far a thinned walk may cut inside (or outside) the edge it follows


class _Ring:
    """One boundary ring of a travel region: closed vertex list and arc length at each vertex."""

    def __init__(self, xy: np.ndarray) -> None:
        self.xy = xy                                            # (n + 1, 2), last == first
        seg = np.hypot(*np.diff(xy, axis=0).T)
        self.pos = np.r_[0.0, np.cumsum(seg)]
        self.length = float(self.pos[-1])

    def walk(self, s_from: float, s_to: float) -> np.ndarray:
        """Ring vertices strictly between arc positions ``s_from`` and ``s_to``, the shorter way round."""
        return ring_walk(self.pos[:-1], self.xy[:-1], self.length, s_from, s_to, (s_to - s_from) % self.length)


class TravelPiece:
    """One connected piece of a travel region, prepared for fast containment tests."""

    def __init__(self, poly: shapely.Polygon) -> None:
        shapely.prepare(poly)
        self.poly = poly
        self.rings = [_Ring(np.asarray(poly.exterior.coords)[:, :2])] + \
            [_Ring(np.asarray(r.coords)[:, :2]) for r in poly.interiors]
        # all ring edges back to back, with the ring and the arc position each starts at
        self.a = np.concatenate([r.xy[:-1] for r in self.rings])
        self.b = np.concatenate([r.xy[1:] for r in self.rings])
        self.ring_of = np.concatenate([np.full(len(r.xy) - 1, k) for k, r in enumerate(self.rings)])
        self.s0 = np.concatenate([r.pos[:-1] for r in self.rings])

    def covers(self, a: np.ndarray, b: np.ndarray) -> bool:
        return bool(shapely.covers(self.poly, shapely.linestrings([a, b])))

    def route(self, a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
        """A path from ``a`` to ``b`` inside this piece (both inside it), or None when none is found."""
        if self.covers(a, b):
            return np.vstack([a, b])
        d = b - a
        e = self.b - self.a
        denom = d[0] * e[:, 1] - d[1] * e[:, 0]
        ok = np.abs(denom) > _EPS
        w = self.a - a
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[:, 0] * e[:, 1] - w[:, 1] * e[:, 0]) / denom        # along a -> b
            u = (w[:, 0] * d[1] - w[:, 1] * d[0]) / denom              # along the edge
        hit = ok & (t > 0) & (t < 1) & (u >= 0) & (u < 1)
        idx = np.flatnonzero(hit)
        if len(idx) < 2:
            return None
        idx = idx[np.argsort(t[idx])]
        if len(idx) % 2:
            return None                   # grazing a vertex: no clean exit / entry pairs
        out = [a]
        for ex, en in zip(idx[0::2], idx[1::2], strict=True):
            if self.ring_of[ex] != self.ring_of[en]:
                return None
            ring = self.rings[int(self.ring_of[ex])]
            p_ex, p_en = a + t[ex] * d, a + t[en] * d
            s_ex = self.s0[ex] + u[ex] * math.hypot(*e[ex])
            s_en = self.s0[en] + u[en] * math.hypot(*e[en])
            out += [p_ex, *ring.walk(s_ex, s_en), p_en]
        out.append(b)
        path = np.asarray(out)
        if len(path) > 3:
            # a walk along a curved edge: thin its points (by at most ``_THIN_MM`` off the edge)
            path = shapely.get_coordinates(shapely.simplify(shapely.linestrings(path), _THIN_MM,
                                                            preserve_topology=False))
        return self._tighten(path) if len(path) <= _TIGHTEN_MAX_POINTS else path

    def _tighten(self, path: np.ndarray) -> np.ndarray:
        """Drop every corner whose neighbours see each other inside the piece, a few passes (each one call)."""
        for _ in range(_TIGHTEN_PASSES):
            if len(path) <= 2:
                break
            lines = shapely.linestrings(np.stack([path[:-2], path[2:]], axis=1))
            cut = shapely.covers(self.poly, lines)         # corner k + 1 can go
            drop = np.zeros(len(path), dtype=bool)
            for k in np.flatnonzero(cut).tolist():          # never two neighbouring corners in one pass
                if not drop[k]:
                    drop[k + 1] = True
            if not drop.any():
                break
            path = path[~drop]
        return path


def travel_pieces(region: shapely.Geometry) -> list[TravelPiece]:
    """The connected pieces of a travel region (a (multi)polygon), ready for routing."""
    return [TravelPiece(p) for p in shapely.get_parts(region) if not p.is_empty and p.area > 0]


class TravelPlanner:
    """Routes and retraction decisions for the travels of one layer.

    ``pieces`` are the pieces of the layer's travel region, ``outline_pieces``
    those of its islands' outlines (the fallback); ``routes`` memoises routes
    across layers.
    """

    def __init__(self, pieces: list[TravelPiece], min_travel_mm: float, inside_max_mm: float,
                 routes: dict[tuple, np.ndarray | None] | None = None,
                 outline_pieces: list[TravelPiece] | None = None) -> None:
        self.tiers = [pieces, outline_pieces or []]
        self.min_travel_mm = min_travel_mm
        self.inside_max_mm = inside_max_mm
        # routes found so far, by piece and end points: a prismatic part repeats its travels layer after layer
        self.routes: dict[tuple, np.ndarray | None] = {} if routes is None else routes

    @staticmethod
    def _piece_of(pieces: list[TravelPiece], xy: np.ndarray) -> TravelPiece | None:
        for piece in pieces:
            if shapely.contains_xy(piece.poly, float(xy[0]), float(xy[1])):
                return piece
        return None

    def plan(self, a: tuple[float, float], b: tuple[float, float]) -> tuple[np.ndarray, bool]:
        """(path from ``a`` to ``b``, retract first?) for one travel."""
        pa, pb = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        straight = np.vstack([pa, pb])
        dist = float(np.hypot(*(pb - pa)))
        if dist <= self.min_travel_mm:
            return straight, False
        for pieces in self.tiers:
            piece = self._piece_of(pieces, pa)
            if piece is None or self._piece_of(pieces, pb) is not piece:
                continue
            key = (id(piece), a[0], a[1], b[0], b[1])
            if key in self.routes:
                path = self.routes[key]
            else:
                path = self.routes[key] = piece.route(pa, pb)
            if path is None:
                continue
            length = float(np.hypot(*np.diff(path, axis=0).T).sum())
            return (straight, True) if length > self.inside_max_mm else (path, False)
        return straight, True
