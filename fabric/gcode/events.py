"""Non-motion commands of a block -> event arrays (temperatures, fan, dwell, firmware retraction)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from fabric.gcode.commands import KNOWN, PARAMS
from fabric.gcode.table import CommandTable, LineError
from fabric.gcode.toolpath import (
    EV_BED_TEMP,
    EV_DWELL,
    EV_EXTRUDE,
    EV_FAN,
    EV_FW_RETRACT,
    EV_FW_UNRETRACT,
    EV_NOZZLE_TEMP,
    WAIT_ANY,
    WAIT_HEAT,
    WAIT_NONE,
)

__all__ = ["command_events", "BlockEvents", "ExtrudeOnly"]

_G = KNOWN
P, S, R, L = (PARAMS.index(c) for c in "PSRL")


class ExtrudeOnly(NamedTuple):
    """Extruder-only moves of a block (no XYZ motion): their 0-based lines and filament."""

    line: np.ndarray
    e_mm: np.ndarray


@dataclass
class BlockEvents:
    """Events of one block in line order (lines 0-based within the block)."""

    line: np.ndarray           # (m,) int64
    kind: np.ndarray           # (m,) uint8 EV_* code
    value: np.ndarray          # (m,) float64 (deg C, fan duty, seconds, filament mm)
    aux: np.ndarray            # (m,) int16 (WAIT_* of heaters)
    n_cnc: int                 # ``G10 L../P..`` (tool offsets: not a retraction, reported unknown)


@dataclass
class _Part:
    rows: np.ndarray           # rows of the command table
    kind: int
    value: np.ndarray
    aux: np.ndarray


def command_events(table: CommandTable, eonly: ExtrudeOnly, errors: list[LineError]) -> BlockEvents:
    """Events of the known non-motion commands of a block and of its extruder-only moves, in line order.

    Negative temperatures and dwells are appended to ``errors``.
    """
    r_line, r_code, par, has = table.line, table.code, table.par, table.has
    g = _G
    parts: list[_Part] = []
    for name, kind, wait in (("M104", EV_NOZZLE_TEMP, False), ("M109", EV_NOZZLE_TEMP, True),
                             ("M140", EV_BED_TEMP, False), ("M190", EV_BED_TEMP, True)):
        sel = np.flatnonzero((r_code == g[name]) & (has[:, S] | has[:, R]))
        val = np.where(has[sel, S], par[sel, S], par[sel, R])
        aux = np.where(has[sel, S], WAIT_HEAT, WAIT_ANY) if wait else np.full(len(sel), WAIT_NONE)
        parts.append(_Part(sel, kind, val, aux))
        neg = sel[val < 0]
        if len(neg):
            errors.append(LineError(int(r_line[neg[0]]), "negative temperature"))
    fan_on = np.flatnonzero(r_code == g["M106"])
    duty = np.clip(np.where(has[fan_on, S], par[fan_on, S], 255.0) / 255.0, 0.0, 1.0)
    parts.append(_Part(fan_on, EV_FAN, duty, np.zeros(len(fan_on))))
    fan_off = np.flatnonzero(r_code == g["M107"])
    parts.append(_Part(fan_off, EV_FAN, np.zeros(len(fan_off)), np.zeros(len(fan_off))))
    dw = np.flatnonzero(r_code == g["G4"])
    dwell = np.where(has[dw, S], par[dw, S], np.where(has[dw, P], par[dw, P] / 1000.0, 0.0))
    if (dwell < 0).any():
        errors.append(LineError(int(r_line[dw[dwell < 0][0]]), "negative dwell"))
    parts.append(_Part(dw, EV_DWELL, dwell, np.zeros(len(dw))))
    g10 = r_code == g["G10"]
    cnc = g10 & (has[:, L] | has[:, P])
    for sel, kind in ((np.flatnonzero(g10 & ~cnc), EV_FW_RETRACT),
                      (np.flatnonzero(r_code == g["G11"]), EV_FW_UNRETRACT)):
        parts.append(_Part(sel, kind, np.zeros(len(sel)), np.zeros(len(sel))))
    lines = np.concatenate([r_line[p.rows] for p in parts] + [eonly.line])
    kinds = np.concatenate([np.full(len(p.rows), p.kind, np.uint8) for p in parts]
                           + [np.full(len(eonly.line), EV_EXTRUDE, np.uint8)])
    values = np.concatenate([p.value for p in parts] + [eonly.e_mm]).astype(np.float64)
    auxs = np.concatenate([p.aux for p in parts] + [np.zeros(len(eonly.line))]).astype(np.int16)
    order = np.argsort(lines, kind="stable")
    return BlockEvents(lines[order], kinds[order], values[order], auxs[order], int(cnc.sum()))
