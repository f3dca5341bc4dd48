"""The certified collision sweep on real coal: the part as printed bead by bead, every motion certified
between configurations, the nozzle's one exemption, and the robot against itself."""
from __future__ import annotations

import numpy as np
import pytest

from fabric.collision.beads import BeadSolids
from fabric.collision.certify import Certifier
from fabric.collision.path import MOVE_KINDS, move_segments, program_segments
from fabric.collision.report import collision_report
from fabric.collision.sweep import CollisionChecker
from fabric.motion.testprog import square_program
from fabric.planning import PlanOptions, plan_gcode
from fabric.robot.cell import Cell
from fabric.services.collision import sweep_program

from support.certify_cells import plan_reachable

pytestmark = pytest.mark.timeout(300)

TOWER_A = (100.0, 120.0, 110.0, 130.0)        # x0, y0, x1, y1 (plate frame, mm)
TOWER_B = (140.0, 120.0, 150.0, 130.0)
TOWER_B_NEAR = (130.0, 120.0, 140.0, 130.0)   # 20 mm from A: a gap the nozzle fits through


def towers_gcode(towers, height_mm: float = 40.0, layer_mm: float = 0.4, tail: tuple[str, ...] = ()) -> str:
    """Square towers printed a layer at a time (each side an extruding move), then ``tail``."""
    lines = ["; towers", "G21", "G90", "M83", "M104 S210", "M109 S210"]
    e_side = 0.6 * layer_mm * 10.0 / (np.pi * 1.425 ** 2)
    for k in range(int(round(height_mm / layer_mm))):
        z = layer_mm * (k + 1)
        lines += [";LAYER_CHANGE", f";Z:{z:.3f}", f"G1 Z{z:.3f} F600"]
        for x0, y0, x1, y1 in towers:
            lines.append(f"G0 X{x0:.3f} Y{y0:.3f} F6000")
            lines += [f"G1 X{x:.3f} Y{y:.3f} E{e_side:.5f} F1200" for x, y in ((x1, y0), (x1, y1), (x0, y1), (x0, y0))]
    return "\n".join(lines + list(tail)) + "\n"


def travel_through(height_mm: float, tower=TOWER_A, z_mm: float = 8.0) -> tuple[str, int]:
    """Two towers, then down beside them and a travel at ``z_mm`` straight through ``tower`` (its line)."""
    x = (tower[0] + tower[2]) / 2.0
    text = towers_gcode([TOWER_A, TOWER_B], height_mm, tail=(
        "G0 Z45 F3000", f"G0 X{x:.1f} Y60 F6000", f"G0 Z{z_mm:g} F3000", f"G0 X{x:.1f} Y160 F6000"))
    return text, len(text.splitlines())


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


def plan(cell: Cell, gcode: str):
    return plan_reachable(cell, gcode)


def report(cert: Certifier, program):
    beads = BeadSolids.from_program(program)
    return collision_report(cert.sweep_program(program, beads=beads), cert, beads, program.wobj, program)


@pytest.mark.parametrize("height_mm", [40.0, 36.0])
def test_a_travel_through_a_printed_tower_is_reported_with_its_line(cell, cert, height_mm):
    gcode, line = travel_through(height_mm)
    program = plan(cell, gcode)
    rep = report(cert, program)
    hit = rep.first_hit
    assert not rep.collision_free and hit is not None
    assert hit.gcode_line == line and hit.kind == "travel" and hit.body_b == "part"
    assert hit.body_a.startswith("tool_") and hit.bead >= 0 and hit.bead_gcode_line > 0
    assert hit.xyz_mm is not None and hit.xyz_mm[2] == pytest.approx(9.0, abs=0.5)   # 8 mm + the travel lift
    assert f"G-code line {line} (travel" in hit.message and "hits the part" in hit.message
    if height_mm == 36.0:   # the tool body passes above this one: the sampled sweep of version 1 missed it
        # (on the program as it was then, each move one row: the pieces of a split travel sample it densely)
        whole = plan_gcode(gcode.encode(), cell, PlanOptions(linear_tol_mm=10.0)).program
        assert sweep_program(CollisionChecker(cell), whole, 2.0, True).collision_free


def test_a_travel_through_a_gap_a_box_per_layer_would_block_is_free(cell, cert):
    gcode = towers_gcode([TOWER_A, TOWER_B_NEAR], tail=(
        "G0 Z45 F3000", "G0 X120 Y60 F6000", "G0 Z15 F3000", "G0 X120 Y160 F6000"))
    program = plan(cell, gcode)
    rep = report(cert, program)
    assert rep.collision_free, rep.first_hit
    # the tip over the plate on the first layer (0.37 mm), or between the towers, 0.23 mm clear (the travel's
    # pieces stray up to linear_tol_mm from its line, fabric/planning/refine.py)
    assert 0.2 < rep.min_distance_mm < 0.45
    assert rep.clearance_body == "tool_tip" and rep.clearance_layer in (0, 99)
    assert rep.segments > 1000 and rep.beads == 2 * 100 * 4
    # the nozzle between the towers is inside version 1's part model (one box per layer)
    from fabric.collision.sweep import layer_boxes
    rows = np.flatnonzero(program.gcode_line == len(gcode.splitlines()))
    row = int(next(r for r in rows if program.xyz_mm[r - 1, 1] < 125.0 < program.xyz_mm[r, 1]))
    prev = row - 1
    f = (125.0 - program.xyz_mm[prev, 1]) / (program.xyz_mm[row, 1] - program.xyz_mm[prev, 1])
    q = program.q_rad[prev] + (program.q_rad[row] - program.q_rad[prev]) * f
    checker = CollisionChecker(cell)
    hit, _, _ = checker.check_configs(q[None], np.array([row]), np.array([program.layer[row]]),
                                      layer_boxes(program, program.wobj))
    assert hit is not None and hit.body_b == "part"


def test_a_fast_joint_move_through_a_thin_pin_between_two_samples_is_caught(cell, cert):
    robot = cell.robot
    q_from = np.radians([-20.0, 30.0, -10.0, 0.0, 70.0, 0.0])
    q_to = np.radians([20.0, 30.0, -10.0, 0.0, 70.0, 0.0])
    q_mid = np.radians([1.0, 30.0, -10.0, 0.0, 70.0, 0.0])   # between the 2-degree samples at 0 and 2 degrees
    tip = robot.fk(q_mid)[:3, 3]
    pin = BeadSolids.from_path(tip[None] + [0.0, 0.0, -5.0], tip[None] + [0.0, 0.0, 25.0], [1.0], [1.0], [0], [0],
                               [-1], np.eye(4))                     # a 1 mm pin standing across the nozzle
    for sample in (0.0, 2.0):                                      # both samples around it clear it
        q = q_mid.copy()
        q[0] = np.radians(sample)
        dist = _distance_to(cert, pin, q)
        assert dist > 2.0, f"the sample at {sample} deg touches the pin ({dist:.2f} mm): not between samples"
    res = cert.sweep_move(q_from, q_to, pin, vel_r=1.0)
    assert not res.collision_free and res.first_hit.other == "part"
    assert res.first_hit.body.startswith("tool_")
    assert 0.3 < res.first_hit.s < 0.7                              # near the middle of the move


def _distance_to(cert: Certifier, beads: BeadSolids, q: np.ndarray) -> float:
    """The tool's distance to ``beads`` at ``q`` (mm), straight from coal."""
    import coal
    bodies = cert.bodies
    bodies.place(q)
    out = np.inf
    for name in ("tool_tip", "tool_nozzle", "tool_body"):
        body = bodies.by_name[name]
        for obj in beads.objects(np.arange(len(beads))):
            res = coal.DistanceResult()
            d = coal.distance(body.geometry, bodies.transform(body), obj.collisionGeometry(), obj.getTransform(),
                              coal.DistanceRequest(), res)
            out = min(out, d * 1000.0)
    return out


def test_a_tool_bent_back_onto_its_own_arm_is_caught():
    """A fat extruder (160 mm across): with the wrist bent back to its limit it meets the forearm."""
    from fabric.robot.cell import CELLS_DIR
    text = (CELLS_DIR / "irb140.toml").read_text().replace("body_diameter_mm = 60.0", "body_diameter_mm = 160.0")
    fat = Cell.from_toml_text(text, CELLS_DIR, "fat-extruder")
    cert = Certifier(fat)
    home = fat.home_q_rad
    res = cert.sweep_move(home, np.radians([0.0, 0.0, 0.0, 0.0, 115.0, 0.0]))
    hit = res.first_hit
    assert hit is not None and (hit.body, hit.other) == ("tool_body", "link_4")
    assert 0.0 < hit.s < 1.0 and hit.q_rad[4] > home[4]
    assert cert.sweep_move(home, np.radians([0.0, 0.0, 0.0, 0.0, 100.0, 0.0])).collision_free


def test_the_nozzle_laying_a_bead_is_never_reported_against_it(cell, cert):
    program = square_program(cell, size_mm=20, layers=6, layer_height_mm=0.5, speed_mm_s=40)
    rep = report(cert, program)
    assert rep.collision_free, rep.first_hit
    # the tip sits on the bead it lays; the layer under it is one layer height down, and so is the plate
    # under the first layer (less the sag of the twin's joint interpolation along a 20 mm side)
    assert 0.35 < rep.min_distance_mm <= 0.5 and rep.clearance_body == "tool_tip"
    assert "tool_tip: r 4 mm x 1 mm" in rep.exemption


def test_the_exemption_zone_is_the_tip_and_its_two_layers_only(cell, cert):
    """A bead of the tip's layer right under it is exempt; the same bead one layer further down is not
    exempt but clear; a bead of an older layer inside the tip is a hit; the nozzle is never exempt."""
    q = np.radians([0.0, 40.0, 10.0, 0.0, 40.0, 0.0])
    T = cell.robot.fk(q)
    tip = T[:3, 3]
    assert np.allclose(T[:3, 2], [0.0, 0.0, -1.0], atol=1e-9)           # the nozzle points straight down

    def bead_at(dz: float, layer: int, width: float = 2.0) -> BeadSolids:   # a bead whose top is dz below the tip
        a, b = tip + [-3.0, 0.0, -dz], tip + [3.0, 0.0, -dz]
        return BeadSolids.from_path(a[None], b[None], [width], [0.5], [layer], [0], [-1], np.eye(4))

    def still(beads: BeadSolids, tip_layer: int):
        return cert.sweep_move(q, q + np.radians([0.0, 0.0, 0.0, 0.0, 0.0, 1.0]), beads, tip_layer=tip_layer)

    touching = bead_at(0.0, layer=7)
    assert still(touching, tip_layer=7).collision_free                  # the bead being laid
    assert still(touching, tip_layer=8).collision_free                  # the layer just under it
    hit = still(touching, tip_layer=9).first_hit                        # two layers down: not exempt
    assert hit is not None and hit.body == "tool_tip" and hit.other == "part"
    inside = bead_at(-0.5, layer=3)                                     # into the tip, an old layer
    assert still(inside, tip_layer=9).first_hit.body == "tool_tip"
    up = bead_at(-1.6, layer=9)                                         # above the tip: the nozzle's
    hit = still(up, tip_layer=9).first_hit
    assert hit is not None and hit.body == "tool_nozzle"                # never exempt


def test_a_restarts_descent_is_certified_with_the_print_exemption_of_its_layer(cell, cert):
    """The straight way down after a restart's joint move: the tip lands on a bead of the layer under the one
    it goes on printing (exempt, as when printing), never on an older one; a bead the tip rested on where the
    move started stays exempt on the way down only if it is of those two layers."""
    q_down = np.radians([0.0, 40.0, 10.0, 0.0, 40.0, 0.0])
    T = cell.robot.fk(q_down)
    tip = T[:3, 3]
    up = T.copy()
    up[2, 3] += 3.0
    q_above = np.asarray(cell.robot.ik(up[None], q_down)[0], dtype=float).reshape(-1, 6)[0]
    assert np.allclose(cell.robot.fk(q_above)[:3, 3], tip + [0.0, 0.0, 3.0], atol=1e-6)
    a, b = tip + [-3.0, 0.0, 0.0], tip + [3.0, 0.0, 0.0]
    landing = BeadSolids.from_path(a[None], b[None], [2.0], [0.5], [7], [0], [-1], np.eye(4))   # its top: the tip

    def kind(res) -> str:
        return MOVE_KINDS[int(res.segs.kind[res.first_hit.segment])]

    # from above it (a joint move that only turns the nozzle), then down onto it
    q_from = q_above + np.radians([0.0, 0.0, 0.0, 0.0, 0.0, 2.0])
    assert cert.sweep_move(q_from, q_above, landing).collision_free           # the joint move alone: 3 mm clear
    for down_layer in (7, 8):                                                   # its layer, or the one above it
        assert cert.sweep_move(q_from, q_above, landing, q_down=q_down, down_layer=down_layer).collision_free
    res = cert.sweep_move(q_from, q_above, landing, q_down=q_down, down_layer=9)   # two layers down: a hit
    assert res.first_hit.body == "tool_tip" and res.first_hit.other == "part" and kind(res) == "descent"
    assert res.first_hit.s > 0.9                                                # at the end of the way down
    # resting on it where the move starts (tip layer 7), up, and down onto it again
    assert cert.sweep_move(q_down, q_above, landing, tip_layer=7, q_down=q_down, down_layer=8).collision_free
    res = cert.sweep_move(q_down, q_above, landing, tip_layer=7, q_down=q_down, down_layer=9)
    assert res.first_hit is not None and kind(res) == "descent"                 # left freely, not landed on


def test_joint_moves_follow_the_twins_path_and_turn_each_joint_monotonically(cell):
    segs = move_segments(cell.robot, cell.home_q_rad, np.radians([40.0, 30.0, -20.0, 90.0, 30.0, -120.0]), 0.7)
    traj = segs.trajectories[int(segs.row[0])]
    q = np.array([traj.at_time(t)[0] for t in np.linspace(0.0, traj.duration, 2001)])
    sign = np.sign(q[-1] - q[0])
    assert np.all(np.diff(q, axis=0) * sign >= -1e-12)                  # what the motion bound relies on
    assert np.allclose(segs.q0[0], cell.home_q_rad) and np.allclose(segs.q1[-1], q[-1])
    program = square_program(cell, size_mm=10, layers=2, layer_height_mm=0.5)
    path = program_segments(program, cell.robot, cell.home_q_rad)
    assert np.allclose(path.q1[:-1], path.q0[1:])                       # one continuous path


@pytest.mark.slow                         # 3 s (not the fast tier)
def test_the_ur5_cell_prints_the_sample_part_collision_free():
    from fabric.demo import sample_model
    from fabric.slicing import load_profile, slice_model
    cell = Cell.builtin("ur5")
    model = sample_model()
    gcode = slice_model(model.read_bytes(), model.name, load_profile("robot-1.2mm")).gcode
    program = plan_gcode(gcode, cell, PlanOptions()).program
    rep = report(Certifier(cell), program)
    assert rep.collision_free, rep.first_hit
    assert rep.min_distance_mm > 0.1
