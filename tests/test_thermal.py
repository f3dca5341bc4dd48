"""Heaters: first-order closed form, exact M109/M190 waits, timing of heat-up rows."""
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


def test_first_order_response_and_exact_wait() -> None:
    th = Thermal()
    th.set_target(NOZZLE, 210.0, 5.0)
    p = th.params[NOZZLE]
    assert th.temp_at(NOZZLE, 5.0) == pytest.approx(25.0)
    assert th.temp_at(NOZZLE, 5.0 + p.tau_s) == pytest.approx(210.0 - 185.0 / math.e)
    w = th.wait_s(NOZZLE, 5.0)
    assert w == pytest.approx(p.tau_s * math.log(185.0 / p.tol_c))
    assert th.temp_at(NOZZLE, 5.0 + w) == pytest.approx(210.0 - p.tol_c, abs=1e-9)
    assert th.wait_s(NOZZLE, 5.0 + w + 1.0) == 0.0            # already within tolerance


def test_off_heater_cools_to_ambient_and_waits_nothing() -> None:
    th = Thermal((HeaterParams(tau_s=10.0), HeaterParams(tau_s=50.0, tol_c=1.0, max_c=120.0)))
    th.set_target(BED, 60.0, 0.0)
    hot = th.temp_at(BED, 100.0)
    th.set_target(BED, 0.0, 100.0)
    assert th.wait_s(BED, 100.0) == 0.0
    assert th.temp_at(BED, 100.0) == pytest.approx(hot)
    assert th.temp_at(BED, 1e4) == pytest.approx(25.0)
    with pytest.raises(ValidationError) as e:
        th.set_target(BED, 150.0, 0.0)
    assert e.value.details["heater"] == "bed"
    with pytest.raises(ValidationError):
        th.temp_at(2, 0.0)


def test_heat_up_rows_are_timed_in_closed_form() -> None:
    p = Program.empty(6)
    p.op[:] = [SET_TEMP, SET_TEMP, WAIT_TEMP, WAIT, WAIT_TEMP, WAIT]
    p.aux[:] = [BED, NOZZLE, BED, 0, NOZZLE, 0]
    p.value[:] = [60.0, 200.0, 60.0, 2.0, 200.0, 1.0]
    tl = time_program(p, PointRobot())
    th = Thermal()
    bed_wait = th.params[BED].tau_s * math.log(35.0 / th.params[BED].tol_c)
    assert tl.duration_s[2] == pytest.approx(bed_wait, rel=1e-12)
    # the nozzle heated in parallel during the bed wait and the dwell
    t_noz = bed_wait + 2.0
    gap = 175.0 * math.exp(-t_noz / th.params[NOZZLE].tau_s)
    expect = th.params[NOZZLE].tau_s * math.log(gap / th.params[NOZZLE].tol_c) if gap > th.params[NOZZLE].tol_c else 0.0
    assert tl.duration_s[4] == pytest.approx(expect, abs=1e-9)
    assert tl.total_s == pytest.approx(bed_wait + 2.0 + expect + 1.0, rel=1e-12)
    # a later start (heaters already warm) waits less
    warm = Thermal()
    warm.set_target(NOZZLE, 200.0, 0.0)
    warm.set_target(BED, 60.0, 0.0)
    ss = StartState(np.zeros(6), np.zeros(3), np.array([1.0, 0, 0, 0]), thermal=warm, t0_s=60.0)
    assert time_program(p, PointRobot(), start_state=ss).total_s < tl.total_s
