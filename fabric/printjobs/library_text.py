"""A library file in words: its size, dates and last plan. Pure functions of the entry, shared by
``fabric-cli files`` and the console's Files screen."""
from __future__ import annotations

import time

from fabric import schemas as s
from fabric.printjobs.history import duration_text

__all__ = ["size_text", "date_text", "plan_text"]


def size_text(n_bytes: int) -> str:
    """``512 B``, ``66.9 kB``, ``1.8 MB``, ``2.0 GB``."""
    for unit, k in (("GB", 1 << 30), ("MB", 1 << 20), ("kB", 1 << 10)):
        if n_bytes >= k:
            return f"{n_bytes / k:.1f} {unit}"
    return f"{n_bytes} B"


def date_text(t_s: float) -> str:
    """A wall-clock time as a date and minute (local time); ``-`` for never (0)."""
    return time.strftime("%Y-%m-%d %H:%M", time.localtime(t_s)) if t_s else "-"


def plan_text(entry: s.LibraryFile) -> str:
    """The last plan's layers, volume and duration; ``not planned yet`` before any."""
    if not entry.layers:
        return "not planned yet"
    timed = duration_text(entry.estimate_s) if entry.estimate_s > 0 else "no time estimate"
    return f"{entry.layers} layers, {entry.extruded_mm3:.0f} mm3, {timed}"
