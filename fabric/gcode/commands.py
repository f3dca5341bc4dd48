"""The G/M commands the interpreter understands, and their parameter columns."""
from __future__ import annotations

import numpy as np

__all__ = ["KNOWN", "CODE_NAMES", "code_of", "PARAMS", "COL", "LENGTH_COLS", "FLAG_OK"]

# name -> small integer code
KNOWN: dict[str, int] = {name: i for i, name in enumerate([
    "G0", "G1", "G2", "G3", "G4", "G10", "G11", "G20", "G21", "G28", "G90", "G91", "G92",
    "M82", "M83", "M104", "M109", "M140", "M190", "M106", "M107",
])}
CODE_NAMES = {v: k for k, v in KNOWN.items()}

# (letter index: G = 0, M = 1) * 1000 + number -> code (or -1)
_LUT = np.full(2000, -1, np.int16)
for _name, _code in KNOWN.items():
    _LUT[(_name[0] == "M") * 1000 + int(_name[1:])] = _code

# Parameter letters kept for known commands, in column order (K: the nozzle axis of the multi-axis dialect,
# with I and J; an arc's centre offset in the plane G17 never changes to, elsewhere, and then ignored).
PARAMS = "XYZEFIJRPSLK"
COL = np.full(256, -1, np.int8)
for _i, _ch in enumerate(PARAMS):
    COL[ord(_ch)] = _i
LENGTH_COLS = [PARAMS.index(ch) for ch in "XYZEFIJRK"]   # scaled by G20 (inches; an axis I J K is normalised)

# Commands whose parameters may be bare letters ("G28 X Y", Prusa's "G28 W").
FLAG_OK = frozenset({KNOWN["G28"]})


def code_of(letter: np.ndarray, value: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Known-command code of command words (``-1`` when unknown), vectorised."""
    is_gm = (letter == ord("G")) | (letter == ord("M"))
    integral = ok & is_gm & (value >= 0) & (value < 1000) & (np.floor(np.nan_to_num(value)) == value)
    key = np.where(integral, (letter == ord("M")) * 1000 + np.nan_to_num(value), 0).astype(np.int64)
    return np.where(integral, _LUT[key], -1).astype(np.int16)
