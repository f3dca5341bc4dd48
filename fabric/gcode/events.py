"""Non-motion commands of a block -> event arrays (temperatures, fan, dwell, firmware retraction)."""
from __future__ import annotations

import numpy as np

from fabric.gcode.commands import KNOWN, PARAMS
from fabric.gcode.toolpath import (EV_BED_TEMP, EV_DWELL, EV_EXTRUDE, EV_FAN, EV_FW_RETRACT,
                                   EV_FW_UNRETRACT, EV_NOZZLE_TEMP, WAIT_ANY, WAIT_HEAT, WAIT_NONE)

__all__ = ["command_events"]

_G = KNOWN
P, S, R, L = (PARAMS.index(c) for c in "PSRL")


def command_events(r_line: np.ndarray, r_code: np.ndarray, par: np.ndarray, has: np.ndarray,
                   eonly: tuple[np.ndarray, np.ndarray], errors: list[tuple[int, str]]
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """Events of the known-command rows of a block, in line order.

    ``eonly`` are the extruder-only moves ``(line, e_mm)``. Returns ``(line,
    kind, value, aux, n_cnc)``: lines are the block's 0-based lines; ``n_cnc``
    counts ``G10 L../P..`` (tool offsets: not a retraction, reported unknown).
    Negative temperatures and dwells are appended to ``errors``.
    """
    g = _G
    parts: list[tuple[np.ndarray, int, np.ndarray, np.ndarray]] = []
    for name, kind, wait in (("M104", EV_NOZZLE_TEMP, False), ("M109", EV_NOZZLE_TEMP, True),
                             ("M140", EV_BED_TEMP, False), ("M190", EV_BED_TEMP, True)):
        sel = np.flatnonzero((r_code == g[name]) & (has[:, S] | has[:, R]))
        val = np.where(has[sel, S], par[sel, S], par[sel, R])
        aux = np.where(has[sel, S], WAIT_HEAT, WAIT_ANY) if wait else np.full(len(sel), WAIT_NONE)
        parts.append((sel, kind, val, aux))
        neg = sel[val < 0]
        if len(neg):
            errors.append((int(r_line[neg[0]]), "negative temperature"))
    fan_on = np.flatnonzero(r_code == g["M106"])
    duty = np.clip(np.where(has[fan_on, S], par[fan_on, S], 255.0) / 255.0, 0.0, 1.0)
    parts.append((fan_on, EV_FAN, duty, np.zeros(len(fan_on))))
    fan_off = np.flatnonzero(r_code == g["M107"])
    parts.append((fan_off, EV_FAN, np.zeros(len(fan_off)), np.zeros(len(fan_off))))
    dw = np.flatnonzero(r_code == g["G4"])
    dwell = np.where(has[dw, S], par[dw, S], np.where(has[dw, P], par[dw, P] / 1000.0, 0.0))
    if (dwell < 0).any():
        errors.append((int(r_line[dw[dwell < 0][0]]), "negative dwell"))
    parts.append((dw, EV_DWELL, dwell, np.zeros(len(dw))))
    g10 = r_code == g["G10"]
    cnc = g10 & (has[:, L] | has[:, P])
    for sel, kind in ((np.flatnonzero(g10 & ~cnc), EV_FW_RETRACT),
                      (np.flatnonzero(r_code == g["G11"]), EV_FW_UNRETRACT)):
        parts.append((sel, kind, np.zeros(len(sel)), np.zeros(len(sel))))
    lines = np.concatenate([r_line[p[0]] for p in parts] + [eonly[0]])
    kinds = np.concatenate([np.full(len(p[0]), p[1], np.uint8) for p in parts]
                           + [np.full(len(eonly[0]), EV_EXTRUDE, np.uint8)])
    values = np.concatenate([p[2] for p in parts] + [eonly[1]]).astype(np.float64)
    auxs = np.concatenate([p[3] for p in parts] + [np.zeros(len(eonly[0]))]).astype(np.int16)
    order = np.argsort(lines, kind="stable")
    return lines[order], kinds[order], values[order], auxs[order], int(cnc.sum())
