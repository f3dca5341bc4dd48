"""Travels over a curved part: high enough to clear what is printed so far.

A travel leaves along the nozzle axis, crosses, and comes down along the next
axis (:mod:`.gcode`). On planar layers a lift of a millimetre clears the part:
nothing printed stands above the layer. Curved layers are not level: a
frustum's layers are caps, their middle higher than their rim, so a straight
crossing from one side of the rim to the other passes through the middle,
and a tilted nozzle's tip disc hangs ``r sin a`` below its tip. A
:class:`HeightMap` keeps the highest printed point over each cell of the
plate; a crossing whose straight line would come within ``r sin a`` plus
:data:`TRAVEL_MARGIN_MM` of it (over a corridor the tip's radius wide) goes up
to that height first, crosses level, and comes down over its target. The
margin also covers how far the twin's joint-interpolated path strays from the
straight line while the nozzle turns (up to about a millimetre for the larger
turns between two paths).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["HeightMap", "TRAVEL_MARGIN_MM", "crossing"]

CELL_MM = 0.5                # height map cells
TRAVEL_MARGIN_MM = 1.5       # clearance of the tip disc's low edge over the part on a crossing
BEAD_HALF_MM = 0.25          # the map holds the beads' middles: they reach this much further


class HeightMap:
    """The highest point printed so far over each ``CELL_MM`` cell of the plate (``-inf`` where nothing is)."""

    def __init__(self, lo_mm: np.ndarray, hi_mm: np.ndarray) -> None:
        self.lo = np.asarray(lo_mm, dtype=float)[:2] - 2.0 * CELL_MM
        shape = np.ceil((np.asarray(hi_mm, dtype=float)[:2] + 2.0 * CELL_MM - self.lo) / CELL_MM).astype(int) + 1
        self.z = np.full((int(shape[0]), int(shape[1])), -np.inf)

    def _cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ij = np.floor((xy - self.lo) / CELL_MM).astype(int)
        return np.clip(ij[:, 0], 0, self.z.shape[0] - 1), np.clip(ij[:, 1], 0, self.z.shape[1] - 1)

    def add(self, points_mm: np.ndarray) -> None:
        """Printed points (n, 3): raise their cells to their height."""
        i, j = self._cells(points_mm[:, :2])
        np.maximum.at(self.z, (i, j), points_mm[:, 2])

    def near(self, a_xy: np.ndarray, b_xy: np.ndarray, reach_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """The printed cells within ``reach_mm`` of the segment from ``a_xy`` to ``b_xy``: their heights, and
        where along the segment (0..1) each lies nearest."""
        lo = np.minimum(a_xy, b_xy) - reach_mm
        hi = np.maximum(a_xy, b_xy) + reach_mm
        (i0, i1), (j0, j1) = self._cells(np.vstack([lo, hi]))
        z = self.z[i0:i1 + 1, j0:j1 + 1]
        ii, jj = np.nonzero(np.isfinite(z))
        if len(ii) == 0:
            return np.zeros(0), np.zeros(0)
        centre = self.lo + (np.column_stack([ii + i0, jj + j0]) + 0.5) * CELL_MM
        d = b_xy - a_xy
        t = np.clip((centre - a_xy) @ d / max(float(d @ d), 1e-12), 0.0, 1.0)
        gap = np.linalg.norm(centre - (a_xy + t[:, None] * d), axis=1)
        near = gap <= reach_mm + CELL_MM * math.sqrt(0.5)             # any part of the cell within reach
        return z[ii[near], jj[near]], t[near]


def crossing(up: np.ndarray, up_axis: np.ndarray, above: np.ndarray, above_axis: np.ndarray,
             heights: HeightMap, tip_radius_mm: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """The waypoints (point, axis) between ``up`` (lifted off the last path) and ``above`` (over the next one):
    none when the straight line between them clears the part, else two at a safe height (module docstring)."""
    dip = tip_radius_mm * max(_sin_tilt(up_axis), _sin_tilt(above_axis)) + TRAVEL_MARGIN_MM
    top, t = heights.near(up[:2], above[:2], tip_radius_mm + BEAD_HALF_MM)
    if len(top) == 0 or np.all(up[2] + t * (above[2] - up[2]) - dip >= top):
        return []
    safe = max(float(top.max()) + dip, float(up[2]), float(above[2]))
    return [(np.array([up[0], up[1], safe]), up_axis), (np.array([above[0], above[1], safe]), above_axis)]


def _sin_tilt(axis: np.ndarray) -> float:
    return math.sqrt(max(1.0 - float(axis[2]) ** 2, 0.0))
