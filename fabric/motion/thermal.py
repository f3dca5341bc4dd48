"""Nozzle and bed heaters: a lumped thermal mass driven at full power up to its set point, closed form.

Each heater is one lumped mass of heat capacity ``C`` (J/K) losing heat to the
room through a thermal resistance ``R`` (K/W), driven by a heater of full power
``P`` (W): ``C dT/dt = u P - (T - T_amb) / R`` with ``u`` in [0, 1]. The twin's
regulator is ideal (as a tuned PID or MPC controller is, to within a degree):
full power while below the set point, off while above it, and exactly the power
that holds the set point once there. So from a temperature ``T0`` at ``t0``:

- heating (``T0`` below the set point): ``T = T_max + (T0 - T_max) exp(-dt / tau)``
  with ``T_max = T_amb + P R`` (the temperature full power would reach) and
  ``tau = R C``, until the set point is reached, then the set point;
- cooling (above it, or the heater off: set point below ambient, ``M104 S0``):
  ``T = T_amb + (T0 - T_amb) exp(-dt / tau)``, down to the set point (or ambient).

Heating is fast (driven against ``T_max``, far above any set point) and cooling
slow (passive, towards the room): the two are not the same exponential, which a
single first-order lag towards the set point would make them. The response is a
closed form, re-anchored only when a set point changes, so the temperature at
any time is exact however the simulation is stepped.

``SET_TEMP`` (M104/M140) changes the set point and returns at once;
``WAIT_TEMP`` (M109/M190) waits until ``|T - set point| <= tol_c``, which the
closed form gives as a logarithm (0 when already within tolerance, or when the
heater is off: there is nothing to wait for). Cooling down to a lower set point
waits too.

The constants (see :func:`_default_params`):

- nozzle: the E3D V6 hotend with its 40 W cartridge as Prusa Research's
  firmware models it for the Original Prusa i3 MK3S (``Firmware/thermal_model/e3d_v6.h``
  in github.com/prusa3d/Prusa-Firmware: heater power 38 W, heat block capacitance
  12.1 J/K, block-to-ambient resistance 20.5 K/W with the print fan off). That
  gives ``tau`` 248 s: 25 -> 215 C in about 69 s at full power, and a passive
  cool-down from 225 C to 60 C in about 7 minutes;
- bed: a 250 x 250 mm bed of 3 mm aluminium under a 0.5 mm spring-steel sheet
  with a 200 W silicone heater. We found no published curve of such a bed to
  cite, so its constants are computed from material properties (aluminium 506 g
  at 0.90 J/(g K) plus steel 245 g at 0.49 J/(g K): 575 J/K; natural convection
  and radiation of both faces, about 18 W/(m2 K) over 0.0625 m2: 0.89 K/W):
  ``tau`` 512 s, 25 -> 60 C in about 2 minutes, 60 -> 40 C in about 7 minutes,
  the order of the time constants RepRapFirmware's heater tuning (M303, the C of
  M307) reports for printer beds (a few hundred seconds). These are estimates,
  not a measurement.
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
    """A heater and what it heats: full power (W), heat capacity (J/K), thermal resistance to the room
    (K/W); the tolerance of a wait, the ambient temperature and the highest set point allowed."""

    power_w: float
    capacity_j_k: float
    resistance_k_w: float
    tol_c: float = 2.0
    ambient_c: float = AMBIENT_C
    max_c: float = 300.0

    @property
    def tau_s(self) -> float:
        """The time constant of heating and of cooling (R C)."""
        return self.capacity_j_k * self.resistance_k_w

    @property
    def full_power_c(self) -> float:
        """The temperature full power would hold (far above any set point allowed)."""
        return self.ambient_c + self.power_w * self.resistance_k_w


@dataclass(frozen=True)
class HeaterState:
    """A heater anchored at ``t_s``: its temperature then and its set point since."""

    t_s: float
    temp_c: float
    target_c: float


# E3D V6, 40 W cartridge: Prusa-Firmware Firmware/thermal_model/e3d_v6.h (P 38 W, C 12.1 J/K, R 20.5 K/W).
NOZZLE_E3D_V6 = HeaterParams(power_w=38.0, capacity_j_k=12.1, resistance_k_w=20.5, tol_c=2.0, max_c=300.0)
# 250 x 250 mm aluminium bed with a steel sheet, 200 W: estimated from material properties (module docstring).
BED_250_MM = HeaterParams(power_w=200.0, capacity_j_k=575.0, resistance_k_w=0.89, tol_c=1.0, max_c=120.0)


def _default_params() -> tuple[HeaterParams, HeaterParams]:
    return (NOZZLE_E3D_V6, BED_250_MM)


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
        for p in self.params:
            if p.full_power_c <= p.max_c:
                raise ValidationError(f"a heater of {p.power_w:g} W and {p.resistance_k_w:g} K/W cannot reach its "
                                      f"highest set point {p.max_c:g} C", field="params")
        if not self.states:
            self.states = [HeaterState(0.0, p.ambient_c, 0.0) for p in self.params]

    def copy(self) -> Thermal:
        """An independent copy (the states are immutable, the list is not)."""
        return Thermal(self.params, list(self.states))

    def _check(self, heater: int) -> None:
        if heater not in (0, 1):
            raise ValidationError(f"unknown heater id {heater} (0 nozzle, 1 bed)", field="aux", value=heater)

    def _eff(self, heater: int, target_c: float) -> float:
        """Where the heater settles: its set point, or the room when it is off (or set below the room)."""
        return max(target_c, self.params[heater].ambient_c)

    def temp_at(self, heater: int, t_s: float) -> float:
        """Temperature (C) of ``heater`` at time ``t_s`` (not before its anchor)."""
        self._check(heater)
        st, p = self.states[heater], self.params[heater]
        eff = self._eff(heater, st.target_c)
        dt = max(0.0, t_s - st.t_s)
        t0 = st.temp_c
        if t0 < eff:                    # full power towards T_max, held at the set point once there
            t_max = p.full_power_c
            return min(t_max + (t0 - t_max) * math.exp(-dt / p.tau_s), eff)
        # passive cooling towards the room, held at the set point (or the room) once there
        return max(p.ambient_c + (t0 - p.ambient_c) * math.exp(-dt / p.tau_s), eff)

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
        now_c = self.temp_at(heater, t_s)
        if abs(now_c - st.target_c) <= p.tol_c:
            return 0.0
        if now_c < st.target_c:         # heating at full power up to the set point less the tolerance
            t_max = p.full_power_c
            return p.tau_s * math.log((t_max - now_c) / (t_max - (st.target_c - p.tol_c)))
        return p.tau_s * math.log((now_c - p.ambient_c) / (st.target_c + p.tol_c - p.ambient_c))
