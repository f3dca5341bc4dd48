"""The work envelope: targets off the plate or below its surface are reported like unreachable ones."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

from fabric import schemas as s
from fabric.client import Client
from fabric.motion.program import MOVEL
from fabric.planning import PlanOptions, plan_gcode
from fabric.planning.envelope import ENV_BELOW_PLATE, ENV_OFF_PLATE, envelope_status
from fabric.robot.cell import Cell
from fabric.services.planner import PlannerService
from fabric.wire.errors import UnreachableError, ValidationError

pytestmark = pytest.mark.timeout(120)

HEAD = "G21\nG90\nM83\nM104 S200\nM109 S200\nG1 X100 Y100 Z0.3 F3000\nG1 X120 Y100 E1\n"


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


@hsettings(max_examples=200, deadline=None)
@given(st.floats(-50, 300), st.floats(-50, 300), st.floats(-5, 50))
def test_a_target_is_inside_exactly_when_over_the_plate_and_not_below(x: float, y: float, z: float) -> None:
    code = envelope_status(np.array([[x, y, z]]), np.array([True]), np.array([250.0, 250.0, 10.0]))[0]
    over = -1e-3 <= x <= 250.001 and -1e-3 <= y <= 250.001
    assert code == (ENV_BELOW_PLATE if z < -1e-3 else 0 if over else ENV_OFF_PLATE)


@pytest.mark.parametrize("move, reason", [("G1 X260 Y100 E1", "off the plate"), ("G1 X120 Y-5 E1", "off the plate"),
                                          ("G1 X130 Y100 Z-0.5 E1", "below the plate"),
                                          ("G0 X251 Y100", "off the plate")])
def test_targets_outside_name_their_line_and_reason(cell: Cell, move: str, reason: str) -> None:
    res = plan_gcode(HEAD + move + "\nG1 X120 Y120 Z0.3 E1\n", cell)
    assert res.report.first_unreachable == (8, reason)
    assert res.report.counts[reason] >= 1 and res.report.feasible_r < 1.0
    with pytest.raises(UnreachableError) as err:
        res.require_runnable()
    assert (err.value.details["gcode_line"], err.value.details["reason"]) == (8, reason)
    assert "line 8" in str(err.value) and reason in str(err.value)


def test_allowed_they_are_counted_and_the_program_runs(cell: Cell) -> None:
    text = HEAD + "G1 X255 Y100 E1\nG1 X120 Y120 E1\n"
    res = plan_gcode(text, cell, PlanOptions(allow_off_plate=True)).require_runnable()
    # the targets of line 8's move beyond the edge: its own and those a long move is split into (refine.py)
    off = (res.program.op <= MOVEL) & (res.program.xyz_mm[:, 0] > 250.0)
    assert res.report.counts["off the plate"] == np.count_nonzero(off) >= 1 and np.isfinite(res.estimate_s)
    assert 8 in set(res.program.gcode_line[off].tolist()) <= {8, 9}          # line 9's move starts out there
    assert res.program.meta["options"]["allow_off_plate"] is True
    assert plan_gcode(HEAD, cell).report.reachable                    # on the plate: nothing to count
    assert "off the plate" not in plan_gcode(HEAD, cell).report.counts


def test_the_option_must_be_a_boolean() -> None:
    with pytest.raises(ValidationError) as err:
        PlanOptions(allow_off_plate="yes")
    assert err.value.details["field"] == "allow_off_plate"


def test_the_plan_summary_says_so_and_the_request_can_allow_it(session, settings, cell: Cell) -> None:
    planner = PlannerService(session, settings.cell, cell)
    planner.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("planner",), deadline_s=20)
            off = (HEAD + "G1 X270 Y100 E1\n").encode()
            results = []
            for allow in (False, True):
                acc = client.plan(s.PlanRequest(gcode=off, allow_off_plate=allow))
                results.append(client.plan_summary(client.wait_job("planner", acc.job_id, timeout=60).result_id))
            refused, allowed = results
            assert not refused.runnable and refused.first_unreachable.reason == "off the plate"
            assert refused.first_unreachable.gcode_line == 8 and refused.unreachable_by_reason["off the plate"] >= 1
            assert allowed.runnable and allowed.allow_off_plate and allowed.unreachable_by_reason["off the plate"] >= 1
            assert refused.material_source == "assumed" and refused.warnings          # no diameter stated
    finally:
        planner.close()
