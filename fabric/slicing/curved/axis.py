"""The nozzle axis rules: the cell's tilt limit, the tilt allowed near the plate, and how far the axis may
leave the layer normal.

Near the plate. The tool's tip is a disc of radius ``r`` (the nozzle's outer
radius) at the nozzle tip, square to the axis: tilted by ``a`` from +z, its low
edge hangs ``r sin a`` below the tip. With the tip at height ``h`` over the
plate that edge must stay above the first layer's top ``h1`` (it may touch the
beads it lays, never the plate or what lies under them)::

    r sin a <= h - h1

so the first layer (``h = h1``) is laid with a vertical nozzle, and the full
tilt ``a_max`` is allowed from ``h1 + r sin a_max`` up (3.1 mm for ``r`` 4 mm,
the paper's nozzle, and 45 degrees). ``r`` is
:attr:`CurvedOptions.tip_radius_mm`: a bound for any nozzle up to that
radius (the multi-axis cell's is 1 mm).

Over the layer under. A tip whose axis is ``d`` off the layer normal digs its
low edge ``r sin d`` into the layer under it (the tip rides on the top of the
layer it lays): the collision check lets it touch the layer it lays and the one
under (about two layer thicknesses), nothing older. The axis is therefore kept
within :attr:`CurvedOptions.max_axis_deviation_deg` of the layer normal (5
degrees: ``1 sin 5 = 0.09`` mm on the multi-axis cell, within the thinnest
layer the bounds allow). Where the layer itself leans further than the tilt
limit plus that, the tilt limit wins and the deviation grows; the slice
reports its largest.

The cell's arm. Where the slicer knows the cell, the tilt limit also depends
on where the nozzle is and which way it leans: what the arm holds there
without a joint at its limit or the wrist at its singularity
(:mod:`.cell_tilt`). :class:`TiltLimits` is the one rule every step asks (the
field's axes, the band's direction, the paths' axes, the nozzle's reach).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from fabric.slicing.curved.cell_tilt import CellTilts

__all__ = ["limit_tilt", "limit_deviation", "plate_tilt_deg", "smooth_along", "unit_rows", "TiltLimits"]

AXIS_SMOOTHING_PASSES = 3       # box filters along a path: about a Gaussian


def unit_rows(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` scaled to unit length (zero rows stay zero)."""
    return v / np.maximum(np.sqrt(np.einsum("ij,ij->i", v, v)), 1e-12)[:, None]


def limit_tilt(axes: np.ndarray, max_tilt_deg: float | np.ndarray) -> np.ndarray:
    """Unit axes rotated towards +z (in their vertical plane) so none is tilted more than ``max_tilt_deg``
    (one limit for all, or one per axis)."""
    a = unit_rows(np.asarray(axes, dtype=float))
    limit = np.radians(np.broadcast_to(np.asarray(max_tilt_deg, dtype=float), (len(a),)))
    cos_max = np.cos(limit)
    over = a[:, 2] < cos_max - 1e-12
    if np.any(over):
        horiz = a[over].copy()
        horiz[:, 2] = 0.0
        hn = np.linalg.norm(horiz, axis=1, keepdims=True)
        horiz = np.where(hn > 1e-9, horiz / np.maximum(hn, 1e-12), np.array([1.0, 0.0, 0.0]))
        a[over] = horiz * np.sin(limit[over])[:, None]
        a[over, 2] = cos_max[over]
    return a


def limit_deviation(axes: np.ndarray, normals: np.ndarray, max_deg: float | np.ndarray) -> np.ndarray:
    """Unit axes rotated towards the unit ``normals`` (in the plane of the two) so none is more than
    ``max_deg`` from its normal (one limit for all, or one per axis)."""
    a = unit_rows(np.asarray(axes, dtype=float))
    n = unit_rows(np.asarray(normals, dtype=float))
    cos = np.einsum("ij,ij->i", a, n)
    limit = np.radians(np.broadcast_to(np.asarray(max_deg, dtype=float), (len(a),)))
    over = cos < np.cos(limit) - 1e-12
    if np.any(over):
        side = unit_rows(a[over] - cos[over, None] * n[over])     # in the plane, square to the normal
        flat = np.einsum("ij,ij->i", side, side) < 0.5            # axis opposite the normal: any side will do
        if np.any(flat):
            pick = np.where(np.abs(n[over][flat, 0])[:, None] < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
            side[flat] = unit_rows(np.cross(n[over][flat], pick))
        r = limit[over][:, None]
        a[over] = n[over] * np.cos(r) + side * np.sin(r)
    return a


def plate_tilt_deg(height_mm: np.ndarray, first_layer_mm: float, tip_radius_mm: float,
                   max_tilt_deg: float) -> np.ndarray:
    """The largest tilt (deg) of a tip ``height_mm`` over the plate: ``r sin a <= h - h1`` (module docstring),
    at most ``max_tilt_deg``; 0 at and below the first layer's top."""
    h = np.asarray(height_mm, dtype=float)
    if tip_radius_mm <= 0.0:
        return np.full(h.shape, max_tilt_deg)
    sin_a = np.clip((h - first_layer_mm) / tip_radius_mm, 0.0, 1.0)
    return np.minimum(np.degrees(np.arcsin(sin_a)), max_tilt_deg)


class TiltLimits:
    """The largest tilt (deg) of the nozzle at a point along the way its axis leans: ``max_tilt_deg``, the plate's
    rule for a tip of ``tip_radius_mm`` (:func:`plate_tilt_deg`, heights over ``plate_z_mm``) and, given the
    cell's tilts, what its arm holds there (:class:`.cell_tilt.CellTilts`)."""

    def __init__(self, plate_z_mm: float, first_layer_mm: float, tip_radius_mm: float, max_tilt_deg: float,
                 cell: CellTilts | None = None) -> None:
        self.plate_z_mm = plate_z_mm
        self.first_layer_mm = first_layer_mm
        self.tip_radius_mm = tip_radius_mm
        self.max_tilt_deg = max_tilt_deg
        self.cell = cell

    def deg(self, points_mm: np.ndarray, axes: np.ndarray) -> np.ndarray:
        """(n,) the largest tilt at each point along the lean of its axis (the axis's tilt is not looked at)."""
        p = np.asarray(points_mm, dtype=float)
        limit = plate_tilt_deg(p[:, 2] - self.plate_z_mm, self.first_layer_mm, self.tip_radius_mm, self.max_tilt_deg)
        if self.cell is None or len(p) == 0:
            return limit
        return np.minimum(limit, self.cell.limit_deg(p, axes))

    def hold(self, points_mm: np.ndarray, axes: np.ndarray) -> np.ndarray:
        """Unit ``axes`` turned towards +z, in their vertical plane, where they lean past the limit."""
        return limit_tilt(axes, self.deg(points_mm, axes))


def smooth_along(points_mm: np.ndarray, axes: np.ndarray, closed: bool, width_mm: float,
                 passes: int = AXIS_SMOOTHING_PASSES) -> np.ndarray:
    """Unit axes averaged along a path over a window ``width_mm`` long (by arc length; ``passes`` box
    filters, about a Gaussian), around a closed path's end. The field's axes are interpolated in its
    elements, so along a path they wobble on the element's scale: a turn of 5 degrees within 0.2 mm sags the
    joint-interpolated tip of the twin 0.26 mm under the straight move."""
    n = len(points_mm)
    if n < 3 or width_mm <= 0.0:
        return unit_rows(axes)
    step = np.sqrt(np.einsum("ij,ij->i", np.diff(points_mm, axis=0), np.diff(points_mm, axis=0)))
    s = np.concatenate([[0.0], np.cumsum(step)])
    a = np.asarray(axes, dtype=float)
    if closed:                      # the first point repeats at the end: smooth the loop without it
        total = s[-1]
        s, a = s[:-1], a[:-1]
        if total <= 0.0:
            return unit_rows(axes)
        reach = min(passes * width_mm, total)
        before, after = s >= total - reach, s <= reach
        s = np.concatenate([s[before] - total, s, s[after] + total])
        a = np.concatenate([a[before], a, a[after]])
    half = 0.5 * width_mm
    for _ in range(passes):
        # the running integral of the piecewise-linear axis, read at both ends of every point's window
        mid = 0.5 * (a[1:] + a[:-1]) * np.diff(s)[:, None]
        integral = np.vstack([np.zeros((1, 3)), np.cumsum(mid, axis=0)])
        lo, hi = np.maximum(s - half, s[0]), np.minimum(s + half, s[-1])
        span = np.maximum(hi - lo, 1e-12)
        a = np.column_stack([np.interp(hi, s, integral[:, k]) - np.interp(lo, s, integral[:, k])
                             for k in range(3)]) / span[:, None]
    if closed:
        a = a[int(before.sum()):int(before.sum()) + n - 1]
        a = np.vstack([a, a[:1]])
    return unit_rows(a)
