"""The timed joint reference the station fills and a driver follows.

The station's clock thread samples the twin's commanded joints a little ahead of now (``put``: joints at
times on this host's monotonic clock); the driver's streaming thread asks where the robot should be at each
control step (``at``): the joints interpolated linearly between samples, and their rate. A later ``put``
replaces what was ahead from its first time on (a pause changes the future). Past the last sample the
reference holds it with zero rate and says it ran dry: a station that stalls or dies stops the robot where
the plan had it, on the path.
"""
from __future__ import annotations

import threading

import numpy as np

__all__ = ["Reference", "KEEP_BEHIND_S"]

KEEP_BEHIND_S = 1.0
"""Samples older than this behind the newest put's first time are dropped."""


class Reference:
    """Joint positions at monotonic times; written by one thread, read by another (a window swapped whole)."""

    def __init__(self, dof: int) -> None:
        self.dof = dof
        self._win: tuple[np.ndarray, np.ndarray] = (np.zeros(0), np.zeros((0, dof)))
        self._lock = threading.Lock()          # writers only: a reader takes the window as one reference

    def hold(self, q_rad: np.ndarray, t_s: float) -> None:
        """Stand at ``q_rad`` from ``t_s`` on (the robot's pose on connecting, or the twin's at rest)."""
        self.put(np.array([t_s]), np.asarray(q_rad, dtype=float).reshape(1, self.dof))

    def put(self, t_s: np.ndarray, q_rad: np.ndarray) -> None:
        """Samples at increasing times ``t_s`` (M,) of joints ``q_rad`` (M, dof): they replace what was ahead
        from ``t_s[0]`` on."""
        t_new = np.asarray(t_s, dtype=float).reshape(-1)
        q_new = np.asarray(q_rad, dtype=float).reshape(len(t_new), self.dof)
        if not len(t_new):
            return
        if np.any(np.diff(t_new) <= 0) or not np.all(np.isfinite(t_new)) or not np.all(np.isfinite(q_new)):
            raise ValueError("a reference's times must increase and its joints be finite")
        with self._lock:
            t_old, q_old = self._win
            keep = (t_old < t_new[0]) & (t_old >= t_new[0] - KEEP_BEHIND_S)
            self._win = (np.concatenate([t_old[keep], t_new]), np.concatenate([q_old[keep], q_new]))

    def at(self, t_s: float) -> tuple[np.ndarray, np.ndarray, bool]:
        """The joints and their rate (rad/s) at ``t_s``, and whether the reference ran dry there (``t_s`` past
        its last sample: the last sample, at rest)."""
        t, q = self._win
        if not len(t):
            raise LookupError("the reference is empty: hold a pose first")
        if t_s >= t[-1]:
            return q[-1].copy(), np.zeros(self.dof), t_s > t[-1]
        i = int(np.searchsorted(t, t_s, side="right"))
        if i == 0:
            return q[0].copy(), np.zeros(self.dof), False
        dt = t[i] - t[i - 1]
        rate = (q[i] - q[i - 1]) / dt
        return q[i - 1] + rate * (t_s - t[i - 1]), rate, False

    def between(self, t0_s: float, t1_s: float) -> np.ndarray:
        """The samples' joints (K, dof) from ``t0_s`` to ``t1_s``, with the reference at both ends."""
        t, q = self._win
        if not len(t):
            return np.zeros((0, self.dof))
        inside = q[(t > t0_s) & (t < t1_s)]
        return np.vstack([self.at(t0_s)[0][None], inside, self.at(t1_s)[0][None]])

    def last(self) -> tuple[float, np.ndarray] | None:
        """The last sample (time, joints), or None when empty."""
        t, q = self._win
        return (float(t[-1]), q[-1].copy()) if len(t) else None
