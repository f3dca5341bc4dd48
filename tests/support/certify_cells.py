"""What the collision-check tests share: planning a test program on a cell (their ``cert`` fixture is in
conftest.py)."""
from __future__ import annotations

from fabric.motion.program import Program
from fabric.planning import PlanOptions, plan_gcode
from fabric.robot.cell import Cell


def plan_reachable(cell: Cell, gcode: str) -> Program:
    """The program of ``gcode`` on ``cell``, every target reachable."""
    result = plan_gcode(gcode.encode(), cell, PlanOptions())
    assert result.report.reachable
    return result.program
