"""Cold extrusion: which minimum nozzle temperature a program's material needs, and where a program
would extrude below it.

The minimum is the program's ``min_extrude_temp_c`` (what the G-code's header
states, :mod:`fabric.gcode.material`); else 170 C, as printer firmware, when
the program heats the nozzle; else none (a material extruded cold: clay,
concrete). The twin's interlock (:mod:`fabric.sim.runner`) and the planner's
check use this one rule.

The planner's check follows the nozzle's set point through the program and
what is known of its temperature, from a cold start (the nozzle at ambient):
a SET_TEMP row (M104) changes the set point, and the nozzle is no hotter than
before until something waits for it; a WAIT_TEMP row (M109) waits until the
nozzle is at the set point. An extruding row (a linear move with flow) is
cold when the set point is below the minimum (``set below the minimum``), or
when the set point is high enough but nothing has waited for the nozzle to get
there (``not heated``: the twin, starting cold, would reach the row with the
nozzle still heating).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabric.motion.program import MOVEL, NOZZLE, SET_TEMP, WAIT_TEMP, Program
from fabric.motion.thermal import AMBIENT_C
from fabric.wire.errors import COLD_EXTRUSION_REASONS

__all__ = ["DEFAULT_MIN_EXTRUDE_C", "ColdExtrusion", "min_extrude_c", "first_cold_extrusion"]

DEFAULT_MIN_EXTRUDE_C = 170.0
SET_BELOW, NOT_HEATED = COLD_EXTRUSION_REASONS


def min_extrude_c(program: Program) -> float | None:
    """The minimum extrusion temperature of ``program``'s material (see the module docstring)."""
    if "min_extrude_temp_c" in program.meta:
        return float(program.meta["min_extrude_temp_c"])
    heats = bool(np.any((program.op == SET_TEMP) & (program.aux == NOZZLE) & (program.value > 0)))
    return DEFAULT_MIN_EXTRUDE_C if heats else None


@dataclass(frozen=True)
class ColdExtrusion:
    """The first row that would extrude cold: where (program row, G-code line), the set point in force
    and the line that set it (-1: never set), the temperature last waited for and its line (None, -1:
    never waited for), the minimum and whether the G-code stated it."""

    row: int
    gcode_line: int
    reason: str
    nozzle_c: float
    set_line: int
    waited_c: float | None
    wait_line: int
    min_c: float
    material: str
    stated: bool

    @property
    def message(self) -> str:
        if self.stated:
            minimum = (f"{self.material}'s" if self.material else "the material's") + \
                f" minimum extrusion temperature {self.min_c:g} C"
        else:
            minimum = f"the minimum extrusion temperature {self.min_c:g} C (the G-code states none: firmware's default)"
        if self.reason == SET_BELOW:
            if self.nozzle_c <= 0:
                how = "with the nozzle heater off " + (f"(M104 S0 at line {self.set_line})" if self.set_line >= 0
                                                       else "(no M104/M109 before it)")
            else:
                how = f"with the nozzle set to {self.nozzle_c:g} C (line {self.set_line})"
            return f"G-code line {self.gcode_line} extrudes {how}, below {minimum}"
        if self.waited_c is None:
            waited = "nothing waits for it to heat"
        else:
            waited = f"the last wait (line {self.wait_line}) was for {self.waited_c:g} C"
        return (f"G-code line {self.gcode_line} extrudes before the nozzle can be at {minimum}: it is set to "
                f"{self.nozzle_c:g} C (line {self.set_line}) but {waited} (an M109 S{self.nozzle_c:g} before line "
                f"{self.gcode_line} would)")

    def details(self) -> dict:
        """The plain fields (for an error's details and the plan summary)."""
        return {"gcode_line": self.gcode_line, "row": self.row, "reason": self.reason, "nozzle_c": self.nozzle_c,
                "set_line": self.set_line, "waited_c": self.waited_c, "wait_line": self.wait_line,
                "min_c": self.min_c, "material": self.material, "stated": self.stated}


def first_cold_extrusion(program: Program) -> ColdExtrusion | None:
    """The first row of ``program`` that would extrude below its material's minimum, else None."""
    min_c = min_extrude_c(program)
    if min_c is None:
        return None
    op = program.op
    temp = _nozzle_temp_rows(program)
    # the state after k temperature rows (k = 0: a cold start): set point, its line, lowest temperature
    # known, the temperature last waited for and its line
    n = len(temp)
    set_c, set_line = np.zeros(n + 1), np.full(n + 1, -1, np.int64)
    known = np.full(n + 1, AMBIENT_C)
    waited, wait_line = np.full(n + 1, np.nan), np.full(n + 1, -1, np.int64)
    for k, r in enumerate(temp.tolist(), start=1):
        line = int(program.gcode_line[r])
        if op[r] == SET_TEMP:
            set_c[k], set_line[k] = float(program.value[r]), line
            known[k] = min(known[k - 1], max(set_c[k], AMBIENT_C))
            waited[k], wait_line[k] = waited[k - 1], wait_line[k - 1]
        else:                       # waits until the nozzle is at the set point in force
            set_c[k], set_line[k] = set_c[k - 1], set_line[k - 1]
            known[k] = max(set_c[k], AMBIENT_C)
            waited[k], wait_line[k] = set_c[k], line
    # only the stretches between temperature rows whose state is cold are searched for an extruding row
    bounds = np.concatenate([[0], temp + 1, [len(op)]])
    for k in np.flatnonzero((set_c < min_c) | (known < min_c)).tolist():
        row = _first_extruding(program, int(bounds[k]), int(bounds[k + 1]))
        if row < 0:
            continue
        w = float(waited[k])
        return ColdExtrusion(row=row, gcode_line=int(program.gcode_line[row]),
                             reason=SET_BELOW if set_c[k] < min_c else NOT_HEATED, nozzle_c=float(set_c[k]),
                             set_line=int(set_line[k]), waited_c=None if np.isnan(w) else w,
                             wait_line=int(wait_line[k]), min_c=float(min_c),
                             material=str(program.meta.get("material", "") or ""),
                             stated="min_extrude_temp_c" in program.meta)
    return None


def _first_extruding(program: Program, a: int, b: int, block: int = 1 << 20) -> int:
    """The first row in ``[a, b)`` that extrudes (a linear move with flow), else -1; in blocks of rows."""
    for lo in range(a, b, block):
        hi = min(lo + block, b)
        hit = np.flatnonzero((program.op[lo:hi] == MOVEL) & (program.flow_mm3_mm[lo:hi] > 0))
        if len(hit):
            return lo + int(hit[0])
    return -1


def _nozzle_temp_rows(program: Program, block: int = 1 << 20) -> np.ndarray:
    """The rows that set or wait for the nozzle's temperature, in order (found in blocks of rows)."""
    found = []
    for lo in range(0, len(program.op), block):
        op, aux = program.op[lo:lo + block], program.aux[lo:lo + block]
        found.append(lo + np.flatnonzero(((op == SET_TEMP) | (op == WAIT_TEMP)) & (aux == NOZZLE)))
    return np.concatenate(found) if found else np.zeros(0, np.intp)
