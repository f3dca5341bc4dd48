"""The curved slicer chooses nozzle axes the cell's arm can hold (issue 38): the tilts it holds per place and
direction of lean, agreed with the planner; layers that lean no further than the nozzle can follow; a part
that curls away from the robot (a hook) sliced for the cell plans runnable, and sliced without it does not."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from fabric.planning.planner import plan_gcode
from fabric.planning.report import target_why
from fabric.robot.cell import Cell
from fabric.robot.kinematics import IK_JOINT_LIMIT, IK_OK
from fabric.robot.path_ik import solve_path
from fabric.slicing import load_profile, slice_model
from fabric.slicing.curved.axis import TiltLimits
from fabric.slicing.curved.cell_tilt import TILT_STEP_DEG, CellTilts
from fabric.slicing.curved.heat import fem_operators
from fabric.slicing.curved.lean import LEAN_SLACK_DEG, leaning_over, limit_lean
from fabric.slicing.curved.shapes import hook
from fabric.slicing.curved.tetmesh import tetrahedralise

pytestmark = pytest.mark.timeout(300)

PROFILE = load_profile("taz-pla-medium")
BOX_MM = np.array([[115.0, 115.0, 0.0], [135.0, 135.0, 20.0]])     # round the plate's centre, plate frame


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140-multiaxis")


def _grid() -> np.ndarray:
    axes = [np.linspace(BOX_MM[0, k], BOX_MM[1, k], 5) for k in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def _leaning(azimuth_deg: float, tilt_deg: np.ndarray) -> np.ndarray:
    a, t = np.radians(azimuth_deg), np.radians(tilt_deg)
    return np.column_stack([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)])


def _statuses(cell: Cell, points_mm: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """The planner's IK status of each target (plate frame, nozzle axis from the tip up)."""
    wobj = cell.wobj_T()
    res = solve_path(cell.robot, points_mm @ wobj[:3, :3].T + wobj[:3, 3], -(axes @ wobj[:3, :3].T),
                     cell.home_q_rad)
    return res.status


def test_the_arm_holds_less_tilt_leaning_away_from_it_and_the_planner_agrees(cell):
    """Leaning away from the robot (+x) the wrist bends towards A5's 115 deg: the slicer's table allows less
    tilt there than all round, every target at its limit plans, and a few degrees past it is A5's limit."""
    tilts = CellTilts.of_cell(cell, BOX_MM, 45.0)
    assert tilts is not None
    points = _grid()
    away = tilts.limit_deg(points, _leaning(0.0, np.full(len(points), 30.0)))
    sideways = tilts.limit_deg(points, _leaning(90.0, np.full(len(points), 30.0)))
    assert away.max() < 45.0 - TILT_STEP_DEG + 1e-9 and away.min() > 30.0
    np.testing.assert_array_equal(sideways, 45.0)
    assert np.all(_statuses(cell, points, _leaning(0.0, away)) == IK_OK)
    assert np.all(_statuses(cell, points, _leaning(0.0, away + 8.0)) == IK_JOINT_LIMIT)


def test_an_arm_without_a_closed_form_leaves_the_options_limit_alone(cell):
    class Numeric:
        class robot:
            closed_form = None

    assert CellTilts.of_cell(Numeric(), BOX_MM, 45.0) is None


@pytest.mark.slow
def test_a_hook_curling_away_from_the_robot_plans_runnable_only_when_sliced_for_the_cell(cell):
    """The hook's curl leans its layers past horizontal, away from the robot. Sliced without the cell its
    nozzle leans 45 deg that way and its layers 130 deg: 2676 targets at A5's limit, and the axis 85 deg off
    its layer (the tip in the layer two under; the layers now lean no further than the nozzle can follow, so it
    is less). Sliced for the cell: every axis within what the arm holds, every target reached."""
    model = hook().export(file_type="stl")
    blind = slice_model(model, "hook.stl", PROFILE, layers="curved")
    aware = slice_model(model, "hook.stl", PROFILE, layers="curved", cell=cell)
    plan_blind = plan_gcode(blind.gcode, cell, filename="hook.gcode")
    plan_aware = plan_gcode(aware.gcode, cell, filename="hook.gcode")

    assert not plan_blind.report.reachable
    assert plan_blind.report.counts.get("joint limit", 0) > 100 and set(plan_blind.report.by_joint) == {"A5"}
    row = plan_blind.report.first_unreachable_row
    why = target_why(plan_blind.program, row, "joint limit", cell.name, cell.robot)
    assert why.joint == 5 and why.limit_deg == pytest.approx(115.0) and why.value_deg > 115.0
    assert why.detail.startswith("A5 at ") and "past its limit 115 deg" in why.detail

    assert plan_aware.report.runnable and plan_aware.report.feasible_r == 1.0
    assert plan_aware.report.by_joint == {}
    assert aware.curved["max_axis_deviation_deg"] < LEAN_SLACK_DEG + 5.0     # the tip within one layer
    assert aware.curved["overhang_mm2"] < 0.5 * aware.curved["planar_overhang_mm2"]


def test_layers_leaning_further_than_the_nozzle_can_follow_are_turned_up_and_others_left_alone():
    """A field whose layers lean 85 deg (a curl's) is fitted again to lean no more than the tilt limit (40) and
    the slack (30); one leaning 30 deg is the same array."""
    box = trimesh.creation.box((20.0, 10.0, 10.0))
    box.apply_translation([0.0, 0.0, 5.0])
    mesh = tetrahedralise(box, interior_nodes=3000)
    ops = fem_operators(mesh)
    tilts = TiltLimits(plate_z_mm=0.0, first_layer_mm=0.3, tip_radius_mm=0.0, max_tilt_deg=40.0)


    def leaning(lean_deg: float) -> np.ndarray:          # layers leaning lean_deg towards +x, 0 at a corner
        d = mesh.nodes @ np.array([np.sin(np.radians(lean_deg)), 0.0, np.cos(np.radians(lean_deg))])
        return d - d.min()

    gentle = leaning(30.0)
    assert limit_lean(mesh, ops, gentle, np.array([np.argmin(gentle)]), tilts) is gentle
    steep = leaning(85.0)
    _x, _allowed, over_before = leaning_over(mesh, ops, steep, tilts)
    turned = limit_lean(mesh, ops, steep, np.array([np.argmin(steep)]), tilts)
    _x, _allowed, over_after = leaning_over(mesh, ops, turned, tilts)
    assert over_before.min() > 14.0 and over_after.max() < 1.0
