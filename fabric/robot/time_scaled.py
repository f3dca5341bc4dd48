"""A robot model whose motions are timed slower by a factor, on the same paths.

Scaling every joint's velocity limit by ``r``, its acceleration limit by ``r**2`` and its jerk limit by
``r**3`` scales a jerk-limited trajectory in time by ``1/r`` and leaves its path as it was: what was certified
against the plate and the part still holds. A station that drives a real robot times its own joint moves
(home, the approach, the moves back to a layer) with it: a joint impedance controller follows Franka's
published limits only with torque steps a real FR3 refuses (its torque rate limit is 1000 Nm/s), and unstably
on franky-sim (docs/robots.md).
"""
from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["TimeScaledRobot"]


class TimeScaledRobot:
    """``robot`` (every attribute of it) with its joint limits scaled for motions ``1/r`` as long."""

    def __init__(self, robot: Any, r: float) -> None:
        if not 0.0 < r <= 1.0:
            raise ValueError(f"a time scale must be in (0, 1], got {r}")
        self.base = robot
        self.r = float(r)
        self.vel_limit_rad_s = np.asarray(robot.vel_limit_rad_s, dtype=float) * r
        self.acc_limit_rad_s2 = np.asarray(robot.acc_limit_rad_s2, dtype=float) * r ** 2
        self.jerk_limit_rad_s3 = np.asarray(robot.jerk_limit_rad_s3, dtype=float) * r ** 3

    def __getattr__(self, name: str) -> Any:
        return getattr(self.base, name)
