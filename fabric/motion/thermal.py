"""Nozzle and bed heaters as first-order models with closed-form heating times.

Each heater follows ``dT/dt = (T_eff - T) / tau`` where ``T_eff`` is the set
point, or the ambient temperature when the heater is off (set point below
ambient, e.g. ``M104 S0``). From a temperature ``T0`` at time ``t0`` the
response is ``T(t) = T_eff + (T0 - T_eff) * exp(-(t - t0) / tau)``: a closed
form, so the state is only re-anchored when a set point changes and the
temperature at any time is exact however the simulation is stepped.

``SET_TEMP`` (M104/M140) changes the set point and returns at once;
``WAIT_TEMP`` (M109/M190) waits until ``|T - set point| <= tol_c``. From the
closed form the wait is ``tau * ln(|T0 - T_eff| / tol_c)`` (0 when already
within tolerance, or when the heater is off: there is nothing to wait for).
The wait is symmetric: cooling down to a lower set point waits too.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from fabric.wire.errors import ValidationError

__all__ = ["HeaterParams", "HeaterState", "Thermal", "AMBIENT_C", "HEATER_NAMES"]

AMBIENT_C = 25.0
HEATER_NAMES = ("nozzle", "bed")


@dataclass(frozen=True)
class HeaterParams:
    """Time constant, tolerance of a wait, ambient temperature and the highest set point allowed."""

    tau_s: float
    tol_c: float = 2.0
    ambient_c: float = AMBIENT_C
    max_c: float = 300.0


@dataclass(frozen=True)
class HeaterState:
    """A heater anchored at ``t_s``: its temperature then and its set point since."""

    t_s: float
    temp_c: float
    target_c: float


def _default_params() -> tuple[HeaterParams, HeaterParams]:
    return (HeaterParams(tau_s=20.0, tol_c=2.0, max_c=300.0),
            HeaterParams(tau_s=90.0, tol_c=1.0, max_c=120.0))


@dataclass
class Thermal:
    """Both heaters (index 0 nozzle, 1 bed, as ``program.NOZZLE`` / ``program.BED``).

    The object is small and copied freely: the motion timer takes a copy to
    predict ``WAIT_TEMP`` durations, the twin keeps the live one; both apply the
    same set-point changes at the same times, so they agree exactly.
    """

    params: tuple[HeaterParams, HeaterParams] = field(default_factory=_default_params)
    states: list[HeaterState] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not self.states:
            self.states = [HeaterState(0.0, p.ambient_c, 0.0) for p in self.params]

    def copy(self) -> Thermal:
        """An independent copy (the states are immutable, the list is not)."""
        return Thermal(self.params, list(self.states))

    def _check(self, heater: int) -> None:
        if heater not in (0, 1):
            raise ValidationError(f"unknown heater id {heater} (0 nozzle, 1 bed)", field="aux", value=heater)

    def _eff(self, heater: int, target_c: float) -> float:
        return max(target_c, self.params[heater].ambient_c)

    def temp_at(self, heater: int, t_s: float) -> float:
        """Temperature (C) of ``heater`` at time ``t_s`` (not before its anchor)."""
        self._check(heater)
        st, p = self.states[heater], self.params[heater]
        eff = self._eff(heater, st.target_c)
        dt = max(0.0, t_s - st.t_s)
        return eff + (st.temp_c - eff) * math.exp(-dt / p.tau_s)

    def target(self, heater: int) -> float:
        """Current set point (C; 0 = off)."""
        self._check(heater)
        return self.states[heater].target_c

    def check_target(self, heater: int, target_c: float) -> None:
        """Raise ValidationError unless ``target_c`` is a set point ``heater`` accepts ([0, max_c])."""
        self._check(heater)
        p = self.params[heater]
        if not math.isfinite(target_c) or target_c < 0.0 or target_c > p.max_c:
            raise ValidationError(f"{HEATER_NAMES[heater]} set point {target_c} C outside [0, {p.max_c:g}]",
                                  field="value", heater=HEATER_NAMES[heater], limit=p.max_c)

    def set_target(self, heater: int, target_c: float, t_s: float) -> None:
        """Change the set point at ``t_s`` (re-anchors the closed form there)."""
        self.check_target(heater, target_c)
        self.states[heater] = HeaterState(t_s, self.temp_at(heater, t_s), float(target_c))

    def wait_s(self, heater: int, t_s: float) -> float:
        """Seconds from ``t_s`` until the heater is within tolerance of its set point (closed form)."""
        self._check(heater)
        st, p = self.states[heater], self.params[heater]
        if st.target_c <= p.ambient_c:
            return 0.0
        gap = abs(self.temp_at(heater, t_s) - st.target_c)
        if gap <= p.tol_c:
            return 0.0
        return p.tau_s * math.log(gap / p.tol_c)
