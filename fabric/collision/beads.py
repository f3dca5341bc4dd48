"""The part as printed, bead by bead: one solid per extruding move, in print order.

A bead is the solid the twin deposits for one linear move with the extruder
on (:mod:`fabric.sim.deposition`, whose bead dimensions are used here, not
recomputed): from the move's start to its end, ``width_mm`` wide and
``height_mm`` high, hanging below the nozzle path. Its collision solid is the
box of that width and height along the move (it contains the twin's rounded
cross-section and its octagonal mesh), with x along the move, z along the
nozzle axis the bead was laid with, made normal to the move (the plate
normal for planar printing; a move along the axis itself stands centred on
its path, with any side axis). Beads carry
the program row that laid them (their birth: a motion is checked only against
beads laid before it), their layer and the G-code line.

Coal objects are made lazily, once per bead, and shared by the broad-phase
trees that hold them; the arrays answer the exact queries of the refinement
(which beads lie near a body, were laid before a row, are not exempt).
"""
from __future__ import annotations

from dataclasses import dataclass

import coal
import numpy as np

from fabric.collision.bodies import MM
from fabric.motion.program import MOVEL, Program
from fabric.sim.deposition import UP, Deposition, bead_frames, nozzle_axes

__all__ = ["BeadSolids", "BEAD_ARRAYS"]

BEAD_ARRAYS = ("start_mm", "end_mm", "width_mm", "height_mm", "layer", "row", "axis")
_MIN_LEN_MM = 1e-6


@dataclass
class BeadSolids:
    """Bead boxes in the robot base frame (mm): centre, axes (columns: along, side, up), half extents."""

    centre: np.ndarray          # (n, 3)
    axes: np.ndarray            # (n, 3, 3)
    half: np.ndarray            # (n, 3)
    layer: np.ndarray           # (n,) int
    row: np.ndarray             # (n,) int: the program row that laid it
    gcode_line: np.ndarray      # (n,) int (-1 when not known)

    def __post_init__(self) -> None:
        ext = np.abs(self.axes) @ self.half[:, :, None]
        self.lo = self.centre - ext[:, :, 0]
        self.hi = self.centre + ext[:, :, 0]
        self._objects: list[coal.CollisionObject | None] = [None] * len(self)

    def __len__(self) -> int:
        return len(self.row)

    # --- construction ---------------------------------------------------------------------

    @classmethod
    def empty(cls) -> BeadSolids:
        return cls(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0, np.int64),
                   np.zeros(0, np.int64), np.zeros(0, np.int64))

    @classmethod
    def from_program(cls, program: Program) -> BeadSolids:
        """Every bead ``program`` lays (an extruding linear move after another row), in print order."""
        rows = np.flatnonzero((program.op == MOVEL) & (program.flow_mm3_mm > 0))
        rows = rows[rows > 0]
        dep = Deposition(program)                                 # the twin's bead dimensions
        width, height = dep.dims(program.layer[rows], program.flow_mm3_mm[rows])
        axis = nozzle_axes(program.quat_wxyz[rows]) if program.meta.get("multiaxis", False) else None
        return cls.from_path(program.xyz_mm[rows - 1], program.xyz_mm[rows], width, height, program.layer[rows],
                             rows, program.gcode_line[rows], program.wobj, axis)

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], wobj: np.ndarray,
                    gcode_line: np.ndarray | None = None) -> BeadSolids:
        """Beads as the twin records them (:meth:`Deposition.to_arrays`, plate frame ``wobj``)."""
        n = len(arrays["row"])
        lines = gcode_line if gcode_line is not None else np.full(n, -1, dtype=np.int64)
        axis = arrays.get("axis")
        tilted = axis is not None and len(axis) == n and bool(np.any(np.asarray(axis) != UP))   # else planar
        return cls.from_path(arrays["start_mm"], arrays["end_mm"], arrays["width_mm"], arrays["height_mm"],
                             arrays["layer"], arrays["row"], lines, wobj, axis if tilted else None)

    @classmethod
    def from_path(cls, start_mm: np.ndarray, end_mm: np.ndarray, width_mm: np.ndarray, height_mm: np.ndarray,
                  layer: np.ndarray, row: np.ndarray, gcode_line: np.ndarray, wobj: np.ndarray,
                  axis: np.ndarray | None = None) -> BeadSolids:
        """Boxes of the beads from ``start_mm`` to ``end_mm`` (plate frame ``wobj``, mm), hanging below the path
        along each bead's nozzle axis ``axis`` (plate frame; None: the plate normal, planar printing)."""
        T = np.asarray(wobj, dtype=float)
        a = np.asarray(start_mm, dtype=float).reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]
        b = np.asarray(end_mm, dtype=float).reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]
        n = len(a)
        if axis is not None:
            return cls._tilted(a, b, np.asarray(axis, dtype=float).reshape(n, 3) @ T[:3, :3].T, width_mm, height_mm,
                               layer, row, gcode_line)
        up_plate = T[:3, 2] / np.linalg.norm(T[:3, 2])
        d = b - a
        length = np.linalg.norm(d, axis=1)
        along = np.where(length[:, None] > _MIN_LEN_MM, d / np.maximum(length, _MIN_LEN_MM)[:, None],
                         T[:3, 0] / np.linalg.norm(T[:3, 0]))
        side = np.cross(up_plate, along)
        sn = np.linalg.norm(side, axis=1)
        vertical = sn < 1e-9                                      # a move along the plate normal
        side[vertical] = T[:3, 1] / np.linalg.norm(T[:3, 1])
        side /= np.linalg.norm(side, axis=1)[:, None]
        up = np.cross(along, side)
        w = np.asarray(width_mm, dtype=float).reshape(n)
        h = np.asarray(height_mm, dtype=float).reshape(n)
        half = np.column_stack([np.maximum(length, _MIN_LEN_MM) / 2.0, w / 2.0, h / 2.0])
        hang = np.where(vertical, 0.0, h / 2.0)                     # a column along the normal stays centred
        centre = (a + b) / 2.0 - up * hang[:, None]
        axes = np.stack([along, side, up], axis=2)
        return cls(centre, axes, half, np.asarray(layer, dtype=np.int64).reshape(n),
                   np.asarray(row, dtype=np.int64).reshape(n), np.asarray(gcode_line, dtype=np.int64).reshape(n))

    @classmethod
    def _tilted(cls, a: np.ndarray, b: np.ndarray, axis: np.ndarray, width_mm: np.ndarray, height_mm: np.ndarray,
                layer: np.ndarray, row: np.ndarray, gcode_line: np.ndarray) -> BeadSolids:
        """:meth:`from_path` of beads laid with their own nozzle axes (base frame): the twin's bead frames."""
        n = len(a)
        along, _, up, columnar = bead_frames(b - a, axis)
        length = np.linalg.norm(b - a, axis=1)
        w = np.asarray(width_mm, dtype=float).reshape(n)
        h = np.asarray(height_mm, dtype=float).reshape(n)
        half = np.column_stack([np.maximum(length, _MIN_LEN_MM) / 2.0, w / 2.0, h / 2.0])
        hang = np.where(columnar, 0.0, h / 2.0)
        centre = (a + b) / 2.0 - up * hang[:, None]
        side = np.cross(up, along)                                  # (along, side, up) a proper rotation
        return cls(centre, np.stack([along, side, up], axis=2), half, np.asarray(layer, dtype=np.int64).reshape(n),
                   np.asarray(row, dtype=np.int64).reshape(n), np.asarray(gcode_line, dtype=np.int64).reshape(n))

    def extend(self, more: BeadSolids) -> BeadSolids:
        """These beads followed by ``more`` (the coal objects made so far are kept)."""
        out = BeadSolids(*(np.concatenate([getattr(self, k), getattr(more, k)])
                           for k in ("centre", "axes", "half", "layer", "row", "gcode_line")))
        out._objects = self._objects + more._objects
        return out

    # --- coal objects -----------------------------------------------------------------------

    def objects(self, idx: np.ndarray) -> list[coal.CollisionObject]:
        """Coal objects of beads ``idx`` (metres), made on first use and kept."""
        out = []
        objs = self._objects
        for i in np.asarray(idx, dtype=np.int64).tolist():
            o = objs[i]
            if o is None:
                h = self.half[i] * (2.0 * MM)
                o = coal.CollisionObject(coal.Box(float(h[0]), float(h[1]), float(h[2])), self.axes[i],
                                         self.centre[i] * MM)
                o.computeAABB()
                objs[i] = o
            out.append(o)
        return out

    # --- exact queries ----------------------------------------------------------------------

    def near(self, lo_mm: np.ndarray, hi_mm: np.ndarray, margin_mm: float, mask: np.ndarray | None = None,
             upto: int | None = None) -> np.ndarray:
        """Indices among the first ``upto`` beads (all by default; and where ``mask``) whose box's bounding
        box comes within ``margin_mm`` of the box [lo, hi] (mm)."""
        n = len(self) if upto is None else upto
        lo, hi = np.asarray(lo_mm) - margin_mm, np.asarray(hi_mm) + margin_mm
        hit = np.all((self.lo[:n] <= hi) & (self.hi[:n] >= lo), axis=1)
        if mask is not None:
            hit &= mask
        return np.flatnonzero(hit)
