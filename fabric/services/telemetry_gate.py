"""When a sampled state stream is published: at once when what it says changes, else at a bounded period.

The station publishes pose at ``--pose-hz`` (every sample is a new position).
The extruder's and heaters' streams mostly repeat themselves between changes:
publishing them at the pose rate doubled the messages the hub fans out to every
monitor for nothing. A :class:`ChangeOrPeriod` gate lets a message through when
its *key* (the discrete part: extruder on/off, flow, layer; heater set points)
differs from the last one published, or when ``period_s`` has passed (the
running values: volume, temperatures). The station asks its gates at every
pose sample, so a monitor sees each switch with the first pose sample after it.
"""
from __future__ import annotations

import math
from collections.abc import Hashable

__all__ = ["ChangeOrPeriod", "EXTRUSION_PERIOD_S", "TEMPS_PERIOD_S"]

EXTRUSION_PERIOD_S = 0.05     # extrusion: on every switch, flow or layer change, else 20 Hz (the running volume)
TEMPS_PERIOD_S = 0.1          # temperatures: on a new set point, else 10 Hz


class ChangeOrPeriod:
    """Publish on a change of key, else every ``period_s`` (wall clock); one gate per stream."""

    def __init__(self, period_s: float) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        self.period_s = float(period_s)
        self._key: Hashable = object()         # equal to no key: the first message goes through
        self._last_s = -math.inf

    def due(self, key: Hashable, now_s: float) -> bool:
        """Whether a message with ``key`` at ``now_s`` is published (if so, it becomes the last one)."""
        if key != self._key or now_s - self._last_s >= self.period_s:
            self._key, self._last_s = key, now_s
            return True
        return False
