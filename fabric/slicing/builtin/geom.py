"""Polygon offsets and clean-up shared by the slicer's geometry stages (Clipper-like mitred offsets)."""
from __future__ import annotations

import numpy as np
import shapely

__all__ = ["MITRE", "clean", "offset", "ring_walk"]

MITRE = {"join_style": "mitre", "mitre_limit": 3.0}
_REPEAT_MM = 1e-5           # vertices closer than this are merged


def clean(geom: shapely.Geometry) -> shapely.Geometry:
    """Merge (near-)repeated vertices that boolean operations leave behind.

    GEOS's mitred buffer can return an empty result for a valid polygon with
    vertices 1e-14 mm apart, so every geometry that feeds an offset goes
    through here first.
    """
    try:
        return shapely.remove_repeated_points(geom, _REPEAT_MM)
    except shapely.errors.GEOSException:
        # a sliver collapsed to a 2-point ring: snapping to the grid drops it cleanly
        return shapely.set_precision(geom, _REPEAT_MM)


def offset(geom: shapely.Geometry, distance_mm: float) -> shapely.Geometry:
    """Mitred offset (Clipper-like, limit 3), with a guard against GEOS losing a shape.

    An inward offset by ``d`` can only make a shape vanish if its area is at
    most ``d`` times its perimeter (area = integral of the perimeters of its
    inner parallel sets); an empty result otherwise is a numerical failure,
    retried on a slightly simplified copy.
    """
    # GEOS leaves harmless floating-point flags (division by zero in degenerate joins) that
    # numpy would report as warnings after the ufunc returns.
    with np.errstate(divide="ignore", invalid="ignore"):
        out = shapely.buffer(geom, distance_mm, **MITRE)
        if distance_mm < 0 and out.is_empty and geom.area > -distance_mm * geom.length * 1.01:
            out = shapely.buffer(shapely.simplify(geom, 1e-3), distance_mm, **MITRE)
    return out


def ring_walk(pos: np.ndarray, xy: np.ndarray, length_mm: float, s_from: float, s_to: float,
              fwd: float) -> np.ndarray:
    """A closed ring's vertices strictly between arc positions ``s_from`` and ``s_to``, the shorter way round
    (``fwd``: the forward distance from ``s_from`` to ``s_to``). ``pos`` and ``xy`` hold each vertex once (no
    closing duplicate), ``pos`` its arc position from the first."""
    if fwd <= length_mm - fwd:
        i1 = int(np.searchsorted(pos, s_from, side="right"))
        i2 = int(np.searchsorted(pos, s_to, side="left"))
        return xy[i1:i2] if s_to >= s_from else np.concatenate([xy[i1:], xy[:i2]])
    i1 = int(np.searchsorted(pos, s_to, side="right"))
    i2 = int(np.searchsorted(pos, s_from, side="left"))
    part = xy[i1:i2] if s_from >= s_to else np.concatenate([xy[i1:], xy[:i2]])
    return part[::-1]
