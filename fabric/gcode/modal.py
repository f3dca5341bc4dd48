"""Modal state of a block resolved with cumulative array ops: forward fills and anchored running sums.

* Modes (G20/G21 units, G90/G91, M82/M83) and the feed rate are
  *forward-filled*: the index of the last row that set them, carried with
  ``maximum.accumulate``.
* Positions use an *anchored cumulative sum* per axis: an absolute move or a
  G92 sets the logical coordinate (an anchor), relative moves add to it, so the
  value after row ``k`` is ``anchor + (cumsum[k] - cumsum[anchor])``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["ffill", "anchored", "shifted", "modal_setting"]


def ffill(values: np.ndarray, present: np.ndarray, init: float) -> np.ndarray:
    """Value of the last row at or before each row where ``present`` (``init`` before any)."""
    idx = np.where(present, np.arange(len(values)), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, values[np.maximum(idx, 0)], init)


def anchored(anchor: np.ndarray, anchor_val: np.ndarray, delta: np.ndarray, init: float) -> np.ndarray:
    """Running value: reset to ``anchor_val`` at anchors, plus ``delta`` elsewhere."""
    c = np.cumsum(np.where(anchor, 0.0, delta))
    a = np.where(anchor, np.arange(len(anchor)), -1)
    np.maximum.accumulate(a, out=a)
    ai = np.maximum(a, 0)
    return np.where(a >= 0, anchor_val[ai] + (c - c[ai]), init + c)


def shifted(after: np.ndarray, init: float) -> np.ndarray:
    """The value before each row, given the values after each row (``init`` before the first)."""
    return np.concatenate([[init], after[:-1]])


def modal_setting(code: np.ndarray, on: tuple[int, ...], off: tuple[int, ...], init: float,
                  on_val: float = 1.0, off_val: float = 0.0) -> np.ndarray | float:
    """A modal setting per row (``on_val`` after an ``on`` code, ``off_val`` after an ``off`` one),
    forward-filled from ``init``; just ``init`` when the block never sets it."""
    is_on = np.zeros(len(code), bool)
    is_off = np.zeros(len(code), bool)
    for c in on:
        is_on |= code == c
    for c in off:
        is_off |= code == c
    setting = is_on | is_off
    if not setting.any():
        return init
    return ffill(np.where(is_on, on_val, off_val), setting, init)
