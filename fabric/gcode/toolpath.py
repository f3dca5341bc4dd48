"""The interpreted toolpath: one row per motion segment, columnar, plus events as arrays.

Rows are straight segments in machine coordinates (mm, absolute, after G92
offsets and inch conversion): row ``i`` goes from ``xyz_mm[i - 1]`` (or
``start_xyz_mm`` for the first row) to ``xyz_mm[i]``. Arcs are already expanded
into chords. ``e_mm`` is the filament length fed during the segment (negative
is a retraction while moving). Non-motion commands are *events* attached to the
index of the row they precede (``event_row == len(toolpath)`` after the last
move): temperatures, fan, dwell, firmware retract/unretract and extruder-only
moves (a retract or prime with no XYZ motion).

``feed_mm_s`` is the modal F converted to mm/s (25 mm/s, Marlin's default,
before the first F word). G28 is taken as "this axis is now at 0": the robot
does not home, so the toolpath keeps the G-code's own coordinates.

``axis`` is None for planar G-code (the nozzle vertical, the planner's
``tilt_deg`` aside); for the multi-axis dialect (``fabric.gcode.reader``) it
is the unit nozzle axis of every row, from the tip up the nozzle, in the
G-code frame.

``layer`` is the 0-based sequence number of layer changes (not the slicer's
own number: Cura's raft layers ``;LAYER:-2`` become 0); rows before the first
layer are ``-1``. ``feature`` indexes ``feature_names`` (0 is ``"none"``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fabric.gcode.material import Material

__all__ = [
    "Toolpath", "EV_NOZZLE_TEMP", "EV_BED_TEMP", "EV_FAN", "EV_DWELL", "EV_FW_RETRACT",
    "EV_FW_UNRETRACT", "EV_EXTRUDE", "EVENT_NAMES", "WAIT_NONE", "WAIT_HEAT", "WAIT_ANY", "RowColumns",
]

# Event kinds (``event_kind``) and what ``event_value`` / ``event_aux`` hold.
EV_NOZZLE_TEMP = 0   # value: deg C; aux: WAIT_NONE (M104) / WAIT_HEAT (M109 S) / WAIT_ANY (M109 R)
EV_BED_TEMP = 1      # value: deg C; aux: as above for M140 / M190
EV_FAN = 2           # value: fan duty 0..1 (M106 S/255, M107 = 0)
EV_DWELL = 3         # value: seconds (G4 P ms / S s)
EV_FW_RETRACT = 4    # G10 (firmware retraction, length set in the firmware)
EV_FW_UNRETRACT = 5  # G11
EV_EXTRUDE = 6       # value: filament mm of an extruder-only move (<0 retract, >0 prime)
EVENT_NAMES = {EV_NOZZLE_TEMP: "nozzle_temp", EV_BED_TEMP: "bed_temp", EV_FAN: "fan",
               EV_DWELL: "dwell", EV_FW_RETRACT: "fw_retract", EV_FW_UNRETRACT: "fw_unretract",
               EV_EXTRUDE: "extrude"}
WAIT_NONE, WAIT_HEAT, WAIT_ANY = 0, 1, 2


def _empty(dtype: str, *shape: int) -> np.ndarray:
    return np.zeros((0, *shape), dtype=dtype)


@dataclass
class Toolpath:
    """Columnar toolpath (see the module docstring for the meaning of each column)."""

    start_xyz_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    xyz_mm: np.ndarray = field(default_factory=lambda: _empty("f8", 3))
    e_mm: np.ndarray = field(default_factory=lambda: _empty("f8"))
    feed_mm_s: np.ndarray = field(default_factory=lambda: _empty("f8"))
    line: np.ndarray = field(default_factory=lambda: _empty("i8"))
    layer: np.ndarray = field(default_factory=lambda: _empty("i4"))
    feature: np.ndarray = field(default_factory=lambda: _empty("i2"))
    feature_names: list[str] = field(default_factory=lambda: ["none"])
    event_row: np.ndarray = field(default_factory=lambda: _empty("i8"))
    event_kind: np.ndarray = field(default_factory=lambda: _empty("u1"))
    event_value: np.ndarray = field(default_factory=lambda: _empty("f8"))
    event_aux: np.ndarray = field(default_factory=lambda: _empty("i2"))
    event_line: np.ndarray = field(default_factory=lambda: _empty("i8"))
    layer_z_mm: np.ndarray = field(default_factory=lambda: _empty("f8"))
    unknown_commands: dict[str, int] = field(default_factory=dict)
    n_lines: int = 0
    slicer: str = "unknown"
    material: Material = field(default_factory=Material)     # what the file's comments state
    axis: np.ndarray | None = None         # (N, 3) unit nozzle axis per row (multi-axis dialect); None: planar

    def __len__(self) -> int:
        return len(self.line)

    @property
    def n_layers(self) -> int:
        return len(self.layer_z_mm)

    def starts_mm(self) -> np.ndarray:
        """(N, 3) start point of every row."""
        if len(self) == 0:
            return _empty("f8", 3)
        return np.concatenate([self.start_xyz_mm[None, :], self.xyz_mm[:-1]])

    def segment_length_mm(self) -> np.ndarray:
        """(N,) length of every row's segment."""
        return np.linalg.norm(self.xyz_mm - self.starts_mm(), axis=1)

    def extruding(self) -> np.ndarray:
        """(N,) rows that deposit material (filament fed forward while moving)."""
        return self.e_mm > 0

    def total_filament_mm(self) -> float:
        """Net filament fed over the whole file: moves plus extruder-only moves.

        This is what slicers print as "filament used": retractions and their
        primes cancel out.
        """
        eonly = self.event_value[self.event_kind == EV_EXTRUDE]
        return float(self.e_mm.sum() + eonly.sum())

    def deposited_filament_mm(self) -> float:
        """Filament fed forward while moving: what slicers report as "filament used"."""
        return float(self.e_mm[self.e_mm > 0].sum())

    def events_of(self, kind: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(row, value, aux)`` of the events of one kind."""
        sel = self.event_kind == kind
        return self.event_row[sel], self.event_value[sel], self.event_aux[sel]

    def slice(self, start: int, stop: int) -> Toolpath:
        """Rows ``[start, stop)`` with the events that precede them (event rows made relative)."""
        start, stop = max(0, start), min(len(self), stop)
        sel = (self.event_row >= start) & (self.event_row < stop)
        begin = self.xyz_mm[start - 1] if start > 0 else self.start_xyz_mm
        return Toolpath(
            start_xyz_mm=np.array(begin, dtype=float), xyz_mm=self.xyz_mm[start:stop],
            e_mm=self.e_mm[start:stop], feed_mm_s=self.feed_mm_s[start:stop],
            line=self.line[start:stop], layer=self.layer[start:stop],
            feature=self.feature[start:stop], feature_names=self.feature_names,
            event_row=self.event_row[sel] - start, event_kind=self.event_kind[sel],
            event_value=self.event_value[sel], event_aux=self.event_aux[sel],
            event_line=self.event_line[sel], layer_z_mm=self.layer_z_mm,
            unknown_commands=self.unknown_commands, n_lines=self.n_lines,
            slicer=self.slicer, axis=None if self.axis is None else self.axis[start:stop])

    @property
    def multiaxis(self) -> bool:
        """Whether the rows carry their own nozzle axes (the multi-axis dialect)."""
        return self.axis is not None


class RowColumns:
    """Columns filled block by block (the interpreter's output rows), without a final concatenation.

    Each column is allocated once with a capacity (a size hint, grown by half
    when exceeded); pages of the capacity that are never written are never
    touched, so a generous hint costs address space, not memory. :meth:`take`
    shrinks the columns in place to the rows written.
    """

    def __init__(self, spec: dict[str, tuple[str, tuple[int, ...]]], capacity: int) -> None:
        self.n = 0
        self.cap = max(int(capacity), 1024)
        self.cols = {k: np.empty((self.cap, *shape), dtype) for k, (dtype, shape) in spec.items()}

    def append(self, rows: dict[str, np.ndarray]) -> None:
        """Append a block of rows (every column, same length)."""
        m = len(next(iter(rows.values())))
        if self.n + m > self.cap:
            self.cap = max(self.n + m, self.cap + self.cap // 2)
            for k, a in self.cols.items():
                grown = np.empty((self.cap, *a.shape[1:]), a.dtype)
                grown[:self.n] = a[:self.n]
                self.cols[k] = grown
        for k, v in rows.items():
            self.cols[k][self.n:self.n + m] = v
        self.n += m

    def take(self) -> dict[str, np.ndarray]:
        """The columns trimmed to the rows written (a shrinking reallocation, no copy)."""
        for a in self.cols.values():
            a.resize((self.n, *a.shape[1:]), refcheck=False)
        return self.cols
