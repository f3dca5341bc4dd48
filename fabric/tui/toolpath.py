"""The toolpath by layer, taken from a robot program once, for the console's live layer view."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabric.motion.program import MOVEL, PRINT, Program

__all__ = ["Toolpath"]


@dataclass(frozen=True)
class Toolpath:
    """Print-section linear moves in the plate frame: segment ``i`` goes from ``start_xy_mm[i]`` to
    ``end_xy_mm[i]``, ends at program row ``row[i]``, belongs to ``layer[i]`` (0-based) and extrudes
    when ``extruding[i]``. ``bounds_mm`` is (x0, y0, x1, y1) over every layer, so the view keeps its
    framing from layer to layer."""

    start_xy_mm: np.ndarray
    end_xy_mm: np.ndarray
    row: np.ndarray
    layer: np.ndarray
    extruding: np.ndarray
    layers_total: int
    bounds_mm: tuple[float, float, float, float]
    curved: bool = False                        # curved layers (a multi-axis program): the view adds a side view
    start_z_mm: np.ndarray | None = None        # segment heights (plate frame), for the side view
    end_z_mm: np.ndarray | None = None
    z_bounds_mm: tuple[float, float] = (0.0, 1.0)

    @classmethod
    def from_program(cls, program: Program) -> Toolpath:
        rows = np.flatnonzero((program.section == PRINT) & (program.op == MOVEL))
        rows = rows[rows > 0]
        start, end = program.xyz_mm[rows - 1, :2], program.xyz_mm[rows, :2]
        extruding = program.flow_mm3_mm[rows] > 0
        layer = program.layer[rows]
        pts = np.concatenate([start[extruding], end[extruding]]) if extruding.any() else np.zeros((1, 2))
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        layers_total = int(layer.max()) + 1 if len(layer) else 0
        z0, z1 = program.xyz_mm[rows - 1, 2], program.xyz_mm[rows, 2]
        zs = np.concatenate([z0[extruding], z1[extruding]]) if extruding.any() else np.zeros(1)
        return cls(start, end, rows, layer, extruding, layers_total,
                   (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])),
                   curved=bool(program.meta.get("multiaxis", False)), start_z_mm=z0, end_z_mm=z1,
                   z_bounds_mm=(float(zs.min()), float(zs.max())))

    def of_layer(self, layer: int) -> np.ndarray:
        """Indices of the segments of one layer."""
        return np.flatnonzero(self.layer == layer)
