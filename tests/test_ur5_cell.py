"""The second shipped cell (UR5 from example-robot-data) runs the whole pipeline: slice, plan, check, print."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fabric.collision.sweep import CollisionChecker
from fabric.demo import sample_model
from fabric.planning import PlanOptions, plan_gcode
from fabric.robot.cell import Cell
from fabric.services.collision import sweep_program
from fabric.sim.twin import Twin
from fabric.slicing import load_profile, slice_model

UR5 = Path(__file__).resolve().parents[1] / "fabric" / "cells" / "ur5.toml"


@pytest.mark.slow                         # 1.7 s (not the fast tier)
def test_sample_part_on_the_ur5_cell():
    cell = Cell.load(UR5)
    model = sample_model()
    gcode = slice_model(model.read_bytes(), model.name, load_profile("robot-1.2mm")).gcode
    plan = plan_gcode(gcode, cell, PlanOptions())
    assert plan.report.reachable and plan.report.feasible_r == 1.0
    fk = cell.robot.fk(plan.program.q_rad[1:-1])                   # numeric IK: check it independently
    plate = np.linalg.inv(plan.program.wobj) @ fk
    assert np.abs(plate[:, :3, 3] - plan.program.xyz_mm[1:-1]).max() < 0.01
    report = sweep_program(CollisionChecker(cell), plan.program, 2.0, True)
    assert report.collision_free and report.checked_configs > 100
    twin = Twin(cell)
    assert twin.load(plan.program).estimate_s == pytest.approx(plan.estimate_s)
    twin.start()
    events = twin.advance(plan.estimate_s + 1.0)
    assert events[-1].kind == "finished" and twin.time_info().elapsed_s == pytest.approx(plan.estimate_s)
