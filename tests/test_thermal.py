"""Heaters: full-power heating and passive cooling in closed form, exact M109/M190 waits, heat-up rows."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fabric.motion.program import BED, NOZZLE, SET_TEMP, WAIT, WAIT_TEMP, Program
from fabric.motion.thermal import HeaterParams, Thermal
from fabric.motion.timing import StartState, time_program
from fabric.wire.errors import ValidationError


class PointRobot:
    """Limits only: the programs here have no motion rows."""

    lower_rad = np.full(6, -1e3)
    upper_rad = np.full(6, 1e3)
    vel_limit_rad_s = np.full(6, 3.0)
    acc_limit_rad_s2 = np.full(6, 12.0)
    jerk_limit_rad_s3 = np.full(6, 120.0)


def test_heat_up_and_cool_down_follow_the_published_hotend_and_bed() -> None:
    """The nozzle is the E3D V6 (40 W) as Prusa's firmware models it; the bed a 250 mm aluminium bed. Heating
    is driven at full power, cooling is passive and slow (the shift in issue 24 saw 225 -> 59 C in 35 s)."""
    th = Thermal()
    th.set_target(NOZZLE, 215.0, 0.0)
    th.set_target(BED, 60.0, 0.0)
    assert 60.0 < th.wait_s(NOZZLE, 0.0) < 80.0                  # about 69 s to 215 C
    assert 90.0 < th.wait_s(BED, 0.0) < 150.0                     # about 2 minutes to 60 C
    th.set_target(NOZZLE, 225.0, 300.0)
    assert th.temp_at(NOZZLE, 600.0) == pytest.approx(225.0) and th.temp_at(BED, 600.0) == pytest.approx(60.0)
    th.set_target(NOZZLE, 0.0, 600.0)                            # heaters off: the print ended
    th.set_target(BED, 0.0, 600.0)
    assert th.temp_at(NOZZLE, 635.0) > 190.0                     # 35 s later: still near 200 C
    assert th.temp_at(BED, 635.0) > 56.0
    minutes_to_60_c = math.log(200.0 / 35.0) * th.params[NOZZLE].tau_s / 60.0
    assert 5.0 < minutes_to_60_c < 10.0
    assert th.temp_at(NOZZLE, 600.0 + 60.0 * minutes_to_60_c) == pytest.approx(60.0)


def test_full_power_response_and_exact_wait() -> None:
    th = Thermal()
    th.set_target(NOZZLE, 210.0, 5.0)
    p = th.params[NOZZLE]
    assert th.temp_at(NOZZLE, 5.0) == pytest.approx(25.0)
    t_max = 25.0 + p.power_w * p.resistance_k_w
    assert th.temp_at(NOZZLE, 15.0) == pytest.approx(t_max - (t_max - 25.0) * math.exp(-10.0 / p.tau_s))
    w = th.wait_s(NOZZLE, 5.0)
    assert w == pytest.approx(p.tau_s * math.log((t_max - 25.0) / (t_max - 210.0 + p.tol_c)))
    assert th.temp_at(NOZZLE, 5.0 + w) == pytest.approx(210.0 - p.tol_c, abs=1e-9)
    assert th.wait_s(NOZZLE, 5.0 + w + 1.0) == 0.0            # already within tolerance
    assert th.temp_at(NOZZLE, 5.0 + 10 * w) == 210.0          # held at the set point, never above
    th.set_target(NOZZLE, 180.0, 1000.0)                       # a lower set point: passive cooling, waited
    w = th.wait_s(NOZZLE, 1000.0)
    assert w == pytest.approx(p.tau_s * math.log((210.0 - 25.0) / (180.0 + p.tol_c - 25.0)))
    assert th.temp_at(NOZZLE, 1000.0 + w) == pytest.approx(180.0 + p.tol_c, abs=1e-9)
    assert th.temp_at(NOZZLE, 1e6) == 180.0


def test_off_heater_cools_to_ambient_and_waits_nothing() -> None:
    th = Thermal((HeaterParams(40.0, 10.0, 20.0), HeaterParams(200.0, 500.0, 1.0, tol_c=1.0, max_c=120.0)))
    th.set_target(BED, 60.0, 0.0)
    hot = th.temp_at(BED, 100.0)
    th.set_target(BED, 0.0, 100.0)
    assert th.wait_s(BED, 100.0) == 0.0
    assert th.temp_at(BED, 100.0) == pytest.approx(hot)
    assert th.temp_at(BED, 1e5) == pytest.approx(25.0)
    with pytest.raises(ValidationError) as e:
        th.set_target(BED, 150.0, 0.0)
    assert e.value.details["heater"] == "bed"
    with pytest.raises(ValidationError):
        th.temp_at(2, 0.0)
    with pytest.raises(ValidationError, match="cannot reach"):     # a heater too weak for its range
        Thermal((HeaterParams(5.0, 10.0, 20.0), HeaterParams(200.0, 500.0, 1.0, max_c=120.0)))


def test_heat_up_rows_are_timed_in_closed_form() -> None:
    p = Program.empty(6)
    p.op[:] = [SET_TEMP, SET_TEMP, WAIT_TEMP, WAIT, WAIT_TEMP, WAIT]
    p.aux[:] = [BED, NOZZLE, BED, 0, NOZZLE, 0]
    p.value[:] = [60.0, 200.0, 60.0, 2.0, 200.0, 1.0]
    tl = time_program(p, PointRobot())
    th = Thermal()
    th.set_target(BED, 60.0, 0.0)
    th.set_target(NOZZLE, 200.0, 0.0)
    bed_wait = th.wait_s(BED, 0.0)
    assert tl.duration_s[2] == pytest.approx(bed_wait, rel=1e-12)
    # the nozzle heated in parallel during the bed wait and the dwell
    expect = th.wait_s(NOZZLE, bed_wait + 2.0)
    assert tl.duration_s[4] == pytest.approx(expect, abs=1e-9)
    assert tl.total_s == pytest.approx(bed_wait + 2.0 + expect + 1.0, rel=1e-12)
    # a later start (heaters already warm) waits less
    warm = Thermal()
    warm.set_target(NOZZLE, 200.0, 0.0)
    warm.set_target(BED, 60.0, 0.0)
    ss = StartState(np.zeros(6), np.zeros(3), np.array([1.0, 0, 0, 0]), thermal=warm, t0_s=60.0)
    assert time_program(p, PointRobot(), start_state=ss).total_s < tl.total_s
