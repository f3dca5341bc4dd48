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
(which beads lie near a body, were laid before a row, are not exempt), many
beads through a grid of their bounding boxes. The broad phase's beads go by
chains (:meth:`BeadSolids.chains`): boxes around runs of consecutive beads,
where those are tight (a curved slicer's many short moves along a smooth
path), fewer objects for the trees to hold and search.
"""
from __future__ import annotations

from dataclasses import dataclass

import coal
import numpy as np

from fabric.collision.bodies import MM
from fabric.collision.support import resting_layers
from fabric.motion.program import MOVEL, Program
from fabric.sim.deposition import UP, Deposition, bead_frames, nozzle_axes

__all__ = ["BeadSolids", "BEAD_ARRAYS"]

BEAD_ARRAYS = ("start_mm", "end_mm", "width_mm", "height_mm", "layer", "row", "axis")
CHAIN_BEADS = 8              # consecutive beads of a layer boxed together for the broad phase
CHAIN_TIGHT_R = 1.5          # where that box is at most this much larger than the beads
GRID_MIN_BEADS = 4096        # fewer beads are scanned to find those near a body; more go in a grid
GRID_AFTER_SCANS = 16        # once they have been scanned this often
GRID_CELL_R = 2.0            # whose cell is this many times the typical bead's size
GRID_MAX_CELLS = 64          # a bead over more cells than this is always looked at
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
        self._grid: _Grid | None = None
        self._scans = 0
        self._rests_on: dict[int, tuple[int, ...]] | None = None

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

    def laid_before(self) -> BeadSolids:
        """These beads as on the plate before a sweep's first row (row -1: obstacles from its start), keeping
        their coal objects and layers (the tip's exemption judges them by their layers, as any bead)."""
        out = BeadSolids(self.centre, self.axes, self.half, self.layer, np.full(len(self), -1, np.int64),
                         self.gcode_line)
        out._objects = self._objects
        return out

    def extend(self, more: BeadSolids) -> BeadSolids:
        """These beads followed by ``more`` (the coal objects made so far are kept)."""
        out = BeadSolids(*(np.concatenate([getattr(self, k), getattr(more, k)])
                           for k in ("centre", "axes", "half", "layer", "row", "gcode_line")))
        out._objects = self._objects + more._objects
        return out

    # --- what the tip may touch ---------------------------------------------------------------

    def exempt_layers(self, tip_layer: int) -> tuple[int, ...]:
        """The layers the tip may touch while it lays ``tip_layer``: that layer, the one before it and any
        other its beads rest on (:func:`fabric.collision.support.resting_layers`, found once)."""
        if self._rests_on is None:                             # found once, on first use
            self._rests_on = resting_layers(self.centre, self.axes, self.half, self.layer)
        return (int(tip_layer), int(tip_layer) - 1, *self._rests_on.get(int(tip_layer), ()))

    # --- coal objects -----------------------------------------------------------------------

    def objects(self, idx: np.ndarray) -> list[coal.CollisionObject]:
        """Coal objects of beads ``idx`` (metres), made on first use and kept."""
        return [self.object(i) for i in np.asarray(idx, dtype=np.int64).tolist()]

    def object(self, i: int) -> coal.CollisionObject:
        """The coal object of bead ``i`` (metres), made on first use and kept."""
        o = self._objects[i]
        if o is None:
            h = self.half[i] * (2.0 * MM)
            o = coal.CollisionObject(coal.Box(float(h[0]), float(h[1]), float(h[2])), self.axes[i],
                                     self.centre[i] * MM)
            o.computeAABB()
            self._objects[i] = o
        return o

    # --- chains: consecutive beads boxed together ------------------------------------------------

    def chains(self) -> tuple[BeadSolids, np.ndarray]:
        """Boxes around runs of consecutive beads of one layer, for the broad phase: (the boxes, as beads
        whose row is their first bead's, and the index of each one's first bead). A run of ``CHAIN_BEADS``
        (else 4, else 2, aligned within its layer) goes in one box along it, turned with the beads' mean
        axis, where that box is no more than ``CHAIN_TIGHT_R`` times their volume (a curved layer's many
        short beads along a smooth path); any other bead is its own box. Each box holds every corner of its
        beads, so a distance to it is a lower bound of the distance to them."""
        n = len(self)
        if n == 0:
            return BeadSolids.empty(), np.zeros(0, np.int64)
        cut = np.concatenate([[0], np.flatnonzero(np.diff(self.layer) != 0) + 1])
        length = np.diff(np.append(cut, n))
        run = np.repeat(np.arange(len(cut)), length)
        pos = np.arange(n) - cut[run]
        room = length[run] - pos                                  # beads left in its layer's run from each
        volume = np.prod(2.0 * self.half, axis=1)
        signs = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
        corners = self.centre[:, None, :] + (signs[None] * self.half[:, None, :]) @ np.swapaxes(self.axes, 1, 2)
        taken = np.zeros(n, bool)
        firsts: list[np.ndarray] = []
        boxes: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        for size in (CHAIN_BEADS, 4, 2):
            first = np.flatnonzero((pos % size == 0) & (room >= size))
            members = first[:, None] + np.arange(size)
            free = ~taken[members].any(axis=1)
            first, members = first[free], members[free]
            if len(first) == 0:
                continue
            centre, axes, half = _chain_boxes(self, members, corners)
            tight = np.prod(2.0 * half, axis=1) <= CHAIN_TIGHT_R * volume[members].sum(axis=1)
            firsts.append(first[tight])
            boxes.append((centre[tight], axes[tight], half[tight]))
            taken[members[tight].ravel()] = True
        single = np.flatnonzero(~taken)
        firsts.append(single)
        boxes.append((self.centre[single], self.axes[single], self.half[single]))
        first = np.concatenate(firsts)
        order = np.argsort(first, kind="stable")
        first = first[order]
        centre, axes, half = (np.concatenate([b[f] for b in boxes])[order] for f in range(3))
        out = BeadSolids(centre, axes, half, self.layer[first], self.row[first], self.gcode_line[first])
        return out, first

    # --- exact queries ----------------------------------------------------------------------

    def near(self, lo_mm: np.ndarray, hi_mm: np.ndarray, margin_mm: float, upto: int | None = None,
             skip_layers: tuple[int, ...] = ()) -> np.ndarray:
        """Indices among the first ``upto`` beads (all by default), but those of layers ``skip_layers``, whose
        box's bounding box comes within ``margin_mm`` of the box [lo, hi] (mm), in order. Many beads asked
        about often are looked up in a grid of their bounding boxes, a few scanned."""
        n = len(self) if upto is None else upto
        lo, hi = np.asarray(lo_mm) - margin_mm, np.asarray(hi_mm) + margin_mm
        if self._grid is None and n >= GRID_MIN_BEADS and self._scans >= GRID_AFTER_SCANS:
            self._grid = _Grid(self.lo, self.hi)                # asked often enough to pay for it
        if n < GRID_MIN_BEADS or self._grid is None:
            self._scans += 1
            idx = np.flatnonzero(np.all((self.lo[:n] <= hi) & (self.hi[:n] >= lo), axis=1))
        else:
            idx = self._grid.query(lo, hi)
            idx = idx[idx < n]
            idx = np.unique(idx[np.all((self.lo[idx] <= hi) & (self.hi[idx] >= lo), axis=1)])   # once, in order
        return idx[~np.isin(self.layer[idx], skip_layers)] if skip_layers else idx


def _chain_boxes(beads: BeadSolids, members: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, ...]:
    """Boxes (centre (G, 3), axes (G, 3, 3), half (G, 3)) around the beads ``members`` (G, k): along the chord
    from the first bead's centre to the last's, up the beads' mean axis made normal to it, holding every
    corner (``corners`` (n, 8, 3))."""
    along = beads.centre[members[:, -1]] - beads.centre[members[:, 0]]
    norm = np.linalg.norm(along, axis=1)
    along = np.where(norm[:, None] > 1e-9, along / np.maximum(norm, 1e-9)[:, None], beads.axes[members[:, 0], :, 0])
    up = beads.axes[members, :, 2].sum(axis=1)
    up -= np.sum(up * along, axis=1)[:, None] * along
    un = np.linalg.norm(up, axis=1)
    ref = np.where((np.abs(along[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    up = np.where(un[:, None] > 1e-6, up, np.cross(along, ref))      # no mean axis across the chord: any normal
    up /= np.linalg.norm(up, axis=1)[:, None]
    axes = np.stack([along, np.cross(up, along), up], axis=2)         # (along, side, up): a proper rotation
    local = (corners[members] @ axes[:, None]).reshape(len(members), -1, 3)   # every corner in the chain's frame
    lo, hi = local.min(axis=1), local.max(axis=1)
    return (axes @ ((lo + hi) / 2.0)[:, :, None])[:, :, 0], axes, (hi - lo) / 2.0


class _Grid:
    """Beads by the cells of a uniform grid that their bounding boxes overlap (cells ``GRID_CELL_R`` times the
    median bead's longest side, 1 to 10 mm): the beads near a box are those of the cells it overlaps (and
    the few too large for cells), found in time independent of the number of beads."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray) -> None:
        self.origin = lo.min(axis=0)
        self.cell = float(np.clip(GRID_CELL_R * np.median(np.max(hi - lo, axis=1)), 1.0, 10.0))
        c0 = np.floor((lo - self.origin) / self.cell).astype(np.int64)
        c1 = np.floor((hi - self.origin) / self.cell).astype(np.int64)
        self.shape = c1.max(axis=0) + 1
        ext = c1 - c0 + 1
        cells = np.prod(ext, axis=1)
        self.big = np.flatnonzero(cells > GRID_MAX_CELLS)
        small = np.flatnonzero(cells <= GRID_MAX_CELLS)
        count = cells[small]
        bead = np.repeat(small, count)
        k = np.arange(len(bead)) - np.repeat(np.cumsum(count) - count, count)   # which of its cells
        e = ext[bead]
        ix = c0[bead, 0] + k // (e[:, 1] * e[:, 2])
        iy = c0[bead, 1] + (k // e[:, 2]) % e[:, 1]
        iz = c0[bead, 2] + k % e[:, 2]
        key = self._key(ix, iy, iz)
        order = np.argsort(key, kind="stable")
        self.keys, first = np.unique(key[order], return_index=True)
        self.edges = np.append(first, len(order))
        self.beads = bead[order]

    def _key(self, ix: np.ndarray, iy: np.ndarray, iz: np.ndarray) -> np.ndarray:
        return (ix * self.shape[1] + iy) * self.shape[2] + iz

    def query(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Every bead whose cells meet the box [lo, hi] (mm), and every large one: once per cell it is in (the
        caller keeps those whose boxes meet, then each once: fewer to sort)."""
        c0 = np.maximum(np.floor((lo - self.origin) / self.cell).astype(np.int64), 0)
        c1 = np.minimum(np.floor((hi - self.origin) / self.cell).astype(np.int64), self.shape - 1)
        if np.any(c1 < c0):
            return self.big
        ix, iy, iz = (np.arange(c0[a], c1[a] + 1) for a in range(3))
        keys = self._key(ix[:, None, None], iy[None, :, None], iz[None, None, :]).ravel()
        pos = np.searchsorted(self.keys, keys)
        pos = pos[(pos < len(self.keys)) & (self.keys[np.minimum(pos, len(self.keys) - 1)] == keys)]
        a, b = self.edges[pos], self.edges[pos + 1]
        size = b - a
        at = np.repeat(a - np.cumsum(size) + size, size) + np.arange(int(size.sum()))
        return np.concatenate([self.beads[at], self.big])
