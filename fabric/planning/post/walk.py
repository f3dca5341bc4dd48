"""One walk over a program's rows for every post-processor: typed events, the extruder state machine once.

The dialects (RAPID, KRL, URScript) differ only in how they spell things;
what happens when is decided here. A :class:`RowWalker` goes through a row
range and yields, in order:

- :class:`Block` before every ``BLOCK_ROWS`` rows, so that a dialect can
  compute its per-row numbers (angles, rotation vectors) for the block at once
  and write its lines out block by block (memory stays flat);
- :class:`LayerStart` when a print row starts a new layer;
- :class:`JointMove` and :class:`LinearMove` for the motion rows;
- :class:`Wait`, :class:`SetTemp`, :class:`WaitTemp` and :class:`Retract` for the others;
- with ``runs=True``, :class:`LinearRun` for a run of consecutive linear moves
  that change nothing (no extruder switch, no new layer), which a dialect
  formats at once as columns of numbers (``numtext.py``) instead of row by row.

Runs. A linear move right after another linear move of the same walk finds
the extruder as that move left it: on at its rate if the rate was positive,
off otherwise. So when both program exactly the same rate it switches
nothing (compared rounded to 1e-3 mm^3/s as the switch does, see
:func:`rounded_rates`), and when it is outside the print, or in the same layer as the row
before, it starts no layer: such a row is *plain*. Plain rows leave every
state as they found it; the walker finds them for a whole block at once.

The extruder. A linear move whose programmed volumetric rate (flow per mm
x speed, rounded to 1e-3 mm^3/s) is positive switches the extruder on, or
changes its rate, *at the start of that move* (path-synchronous where the
controller can): the switch rides on the move as ``LinearMove.extruder``.
The first linear move with rate 0 after extruding switches it off the same
way. Anything that stops the robot or moves it on joints (a joint move, a
dwell, a heater wait, a retraction) is preceded by a plain
:class:`ExtruderOff` if the extruder is on, so nothing is pushed out while
the nozzle stands still.
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from fabric.motion.program import BED, MOVEJ, MOVEL, PRINT, RETRACT, SET_TEMP, WAIT, WAIT_TEMP, Program
from fabric.planning.post.common import BLOCK_ROWS, extrusion_rate, row_blocks
from fabric.wire.errors import ValidationError

__all__ = ["RowWalker", "Event", "Block", "LayerStart", "JointMove", "LinearMove", "LinearRun", "ExtruderOn",
           "ExtruderRate",
           "ExtruderOff", "Wait", "SetTemp", "WaitTemp", "Retract", "NOZZLE_HEATER", "BED_HEATER",
           "heater_index", "rounded_rates"]

NOZZLE_HEATER, BED_HEATER = "nozzle", "bed"


@dataclass(frozen=True, slots=True)
class Block:
    """The rows ``[start, stop)`` follow: compute per-row numbers for them now."""

    start: int
    stop: int


@dataclass(frozen=True, slots=True)
class LayerStart:
    """A print row of a new layer follows."""

    layer: int


@dataclass(frozen=True, slots=True)
class ExtruderOn:
    """Switch the extruder on at ``rate_mm3_s`` (at the start of the move that carries it)."""

    rate_mm3_s: float


@dataclass(frozen=True, slots=True)
class ExtruderRate:
    """The extruder is on: change its rate to ``rate_mm3_s`` (at the start of the move that carries it)."""

    rate_mm3_s: float


@dataclass(frozen=True, slots=True)
class ExtruderOff:
    """Switch the extruder off: at the start of the move that carries it, or at once when on its own."""


@dataclass(frozen=True, slots=True)
class JointMove:
    """Move on joints to the planned joints of ``row``."""

    row: int


@dataclass(frozen=True, slots=True)
class LinearMove:
    """Move linearly to the plate-frame target of ``row``; ``extruder`` switches at the start of the move."""

    row: int
    extruder: ExtruderOn | ExtruderRate | ExtruderOff | None = None


@dataclass(frozen=True, slots=True)
class LinearRun:
    """Linear moves to the targets of rows ``[start, stop)``, none switching the extruder or starting a layer."""

    start: int
    stop: int


@dataclass(frozen=True, slots=True)
class Wait:
    """Dwell for ``duration_s``."""

    row: int
    duration_s: float


@dataclass(frozen=True, slots=True)
class SetTemp:
    """Set a heater (``NOZZLE_HEATER`` or ``BED_HEATER``) to ``temp_c``."""

    row: int
    heater: str
    temp_c: float


@dataclass(frozen=True, slots=True)
class WaitTemp:
    """Wait until the heater has reached its set point (always after its :class:`SetTemp`)."""

    row: int
    heater: str
    temp_c: float


@dataclass(frozen=True, slots=True)
class Retract:
    """Move the filament by ``length_mm`` (< 0 retracts, > 0 primes)."""

    row: int
    length_mm: float


Event = (Block | LayerStart | JointMove | LinearMove | LinearRun | ExtruderOff | Wait | SetTemp | WaitTemp
         | Retract)

_OFF = ExtruderOff()
MIN_RUN_ROWS = 16       # shorter runs of plain rows go as single moves (a run costs a few column operations)


class RowWalker:
    """Walks row ranges of one program, keeping the extruder and layer state from one range to the next.

    RAPID writes the approach and the return home before the print modules,
    each from an extruder known to be off: :meth:`extruder_reset` says so.
    """

    def __init__(self, program: Program, block_rows: int = BLOCK_ROWS, runs: bool = False) -> None:
        self.program = program
        self.block_rows = block_rows
        self.runs = runs
        # the rates of the rows of the block being walked (and the row before it), from row rate_base on:
        # computed block by block, so the walker holds a block's worth whatever the program's length
        self.rate_base = 0
        self.rate_mm3_s = np.zeros(0)
        self.rounded_rate_mm3_s: np.ndarray | None = None
        self.extruding = False
        self.current_rate_mm3_s = -1.0
        self.layer = -2

    def extruder_reset(self) -> None:
        """The extruder is off here whatever the rows before left it as (the caller switched it off)."""
        self.extruding = False

    def walk(self, start: int = 0, stop: int | None = None) -> Iterator[Event]:
        """The events of rows ``[start, stop)`` (the whole program by default)."""
        p = self.program
        stop = len(p) if stop is None else stop
        for a, b in row_blocks(start, stop, self.block_rows):
            p.release_pages(0, a)       # a program mapped from files: the rows walked past go (read again if need be)
            self.rate_base = max(a - 1, 0)
            self.rate_mm3_s = extrusion_rate(p, self.rate_base, b)
            self.rounded_rate_mm3_s = rounded_rates(self.rate_mm3_s) if self.runs else None
            yield Block(a, b)
            if not self.runs:
                yield from self._rows(a, b)
                continue
            first = a
            for run_start, run_stop in self._plain_runs(a, b, start):
                yield from self._rows(first, run_start)
                yield LinearRun(run_start, run_stop)
                first = run_stop
            yield from self._rows(first, b)

    def _rows(self, a: int, b: int) -> Iterator[Event]:
        # rows [a, b) one by one, through the state machine
        p = self.program
        ops = p.op[a:b].tolist()
        layers = p.layer[a:b].tolist()
        in_print = (p.section[a:b] == PRINT).tolist()
        for k, op in enumerate(ops):
            i = a + k
            if in_print[k] and layers[k] != self.layer:
                self.layer = layers[k]
                yield LayerStart(self.layer)
            if op == MOVEL:
                yield LinearMove(i, self._switch(i))
            elif op == MOVEJ:
                yield from self._off()
                yield JointMove(i)
            else:
                yield from self._other(op, i)

    def _plain_runs(self, a: int, b: int, walk_start: int) -> list[tuple[int, int]]:
        """``[start, stop)`` of the runs of at least ``MIN_RUN_ROWS`` plain rows in ``[a, b)`` (module docstring)."""
        p, rate = self.program, self.rounded_rate_mm3_s
        assert rate is not None, "runs are looked for only by a walker made with runs=True"
        lo = max(a, walk_start + 1)                 # a plain row follows a row of this walk
        if b - lo < MIN_RUN_ROWS:
            return []
        prev, cur = slice(lo - 1, b - 1), slice(lo, b)
        r0 = self.rate_base
        in_print = p.section[lo - 1:b] == PRINT
        plain = ((p.op[cur] == MOVEL) & (p.op[prev] == MOVEL)
                 & (rate[lo - r0:b - r0] == rate[lo - 1 - r0:b - 1 - r0])
                 & (~in_print[1:] | (in_print[:-1] & (p.layer[cur] == p.layer[prev]))))
        edges = np.diff(plain.astype(np.int8), prepend=np.int8(0), append=np.int8(0))
        starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        keep = stops - starts >= MIN_RUN_ROWS
        return [(lo + int(s0), lo + int(s1)) for s0, s1 in zip(starts[keep], stops[keep], strict=True)]

    def _switch(self, i: int) -> ExtruderOn | ExtruderRate | ExtruderOff | None:
        # the rate a linear move programs, against what the extruder does now
        rate = round(float(self.rate_mm3_s[i - self.rate_base]), 3)
        if rate > 0:
            if not self.extruding:
                self.extruding, self.current_rate_mm3_s = True, rate
                return ExtruderOn(rate)
            if rate != self.current_rate_mm3_s:
                self.current_rate_mm3_s = rate
                return ExtruderRate(rate)
            return None
        if self.extruding:
            self.extruding = False
            return _OFF
        return None

    def _off(self) -> Iterator[ExtruderOff]:
        if self.extruding:
            self.extruding = False
            yield _OFF

    def _other(self, op: int, i: int) -> Iterator[Event]:
        p = self.program
        value = float(p.value[i])
        if op == WAIT:
            yield from self._off()
            yield Wait(i, value)
        elif op in (SET_TEMP, WAIT_TEMP):
            heater = BED_HEATER if p.aux[i] == BED else NOZZLE_HEATER
            yield SetTemp(i, heater, value)
            if op == WAIT_TEMP:
                yield from self._off()
                yield WaitTemp(i, heater, value)
        elif op == RETRACT:
            yield from self._off()
            yield Retract(i, value)
        else:
            raise ValidationError(f"row {i}: unknown instruction code {op}", field="op", row=i, value=op)


def heater_index(heater: str) -> int:
    """0 for the nozzle, 1 for the bed (the signal numbering the dialects share)."""
    return 1 if heater == BED_HEATER else 0


def rounded_rates(rate_mm3_s: np.ndarray) -> np.ndarray:
    """``round(rate, 3)`` of every rate, the same doubles as Python's ``round`` (what the switch compares).

    ``np.round`` scales by 1000 and rounds to an integer: it can only disagree
    with Python's correctly rounded ``round`` when the scaled value is within
    its rounding error of a half; those few rates are rounded by Python.
    """
    rate = np.asarray(rate_mm3_s, dtype=np.float64)
    rounded = np.round(rate, 3)
    scaled = rate * 1000.0
    with np.errstate(invalid="ignore"):
        near_half = ~(np.abs(np.abs(scaled - np.floor(scaled)) - 0.5) > 1e-6 * np.maximum(np.abs(scaled), 1.0))
    for i in np.flatnonzero(near_half):
        rounded[i] = round(float(rate[i]), 3)
    return rounded
