"""Multi-axis G-code through the planner and the twin: the nozzle tilted as each move says, beads laid along it."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fabric.collision.beads import BeadSolids
from fabric.motion.program import APPROACH, MOVEL, PRINT
from fabric.planning.options import PlanOptions
from fabric.planning.planner import plan_gcode
from fabric.robot.cell import Cell
from fabric.sim.deposition import Deposition, bead_area_mm2, nozzle_axes
from fabric.sim.twin import Twin
from fabric.wire.errors import ValidationError

HEAD = ("; multiaxis: nozzle axis in I J K\n; filament_diameter = 2.85\n;TYPE:Custom\nM104 S210\nM109 S210\n"
        "G21\nG90\nM83\n")


def tilted_rings(layers: int = 3, n: int = 72, tilt_deg: float = 30.0, radius: float = 15.0) -> str:
    """Rings around the plate's centre, one per layer 0.3 mm apart, the nozzle leaning outwards by ``tilt_deg``
    (more on the upper layers), with a travel that lifts, crosses the ring and turns the nozzle round."""
    out = [HEAD, ";WIDTH:0.450\n"]
    for layer in range(layers):
        z = 0.3 * (layer + 1)
        t = math.radians(tilt_deg * layer / max(layers - 1, 1))
        out.append(f";LAYER_CHANGE\n;Z:{z:.3f}\n;HEIGHT:0.300\n")
        for k in range(n + 1):
            a = 2 * math.pi * k / n
            x, y = 125 + radius * math.cos(a), 125 + radius * math.sin(a)
            i, j, kk = math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)
            move = f"X{x:.4f} Y{y:.4f} Z{z:.3f} I{i:.6f} J{j:.6f} K{kk:.6f}"
            out.append(f"G0 {move} F6000\n" if k == 0 else f"G1 {move} E0.024 F1200\n")
        out.append(f"G0 X{125 - radius:.4f} Y125 Z{z + 2:.3f} I{-math.sin(t):.6f} J0 K{math.cos(t):.6f} F6000\n")
    return "".join(out)


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140-multiaxis")


@pytest.fixture(scope="module")
def planned(cell: Cell):
    return plan_gcode(tilted_rings(), cell, filename="rings.gcode")


def test_every_move_is_planned_with_its_nozzle_axis(planned, cell: Cell) -> None:
    res = planned
    p = res.program
    assert res.report.reachable and res.report.feasible_r == 1.0
    assert p.meta["multiaxis"] is True and p.meta["bead_width_mm"] == pytest.approx(0.45)
    # the TCP's z is minus the nozzle axis on every extruding row: the axis the G-code gave it
    ext = np.flatnonzero((p.op == MOVEL) & (p.flow_mm3_mm > 0))
    axes = nozzle_axes(p.quat_wxyz[ext])
    radial = p.xyz_mm[ext, :2] - 125.0
    tilt = np.degrees(np.arccos(np.clip(axes[:, 2], -1, 1)))
    lay = p.layer[ext]
    # a move's own row ends its G-code line's run of rows; the rows before it in the run lie on the move
    # (a long move split, fabric/planning/refine.py), their axes interpolated between its ends' as the twin does
    own = np.ones(len(ext), dtype=bool)
    own[:-1] = p.gcode_line[ext[:-1]] != p.gcode_line[ext[:-1] + 1]
    assert not own.all() and p.meta["linear_split_rows"] > 0
    for layer, want in ((0, 0.0), (1, 15.0), (2, 30.0)):
        np.testing.assert_allclose(tilt[(lay == layer) & own], want, atol=1e-3)     # the G-code has 6 decimals
        np.testing.assert_allclose(tilt[lay == layer], want, atol=0.05)
    outward = np.einsum("ij,ij->i", radial[lay > 0], axes[lay > 0, :2])
    assert np.all(outward > 0)
    # joints reproduce those poses (FK in the base frame, minus the TCP z = the axis)
    T = cell.robot.fk(p.q_rad[ext])
    z_plate = np.einsum("ji,nj->ni", p.wobj[:3, :3], T[:, :3, 2])
    np.testing.assert_allclose(-z_plate, axes, atol=1e-7)
    # the approach comes down along the first bead's axis (vertical on layer 0)
    app = np.flatnonzero(p.section == APPROACH)
    assert p.xyz_mm[app[0], 2] - p.xyz_mm[app[-1], 2] == pytest.approx(cell.approach_height_mm)


def test_a_travel_that_turns_the_nozzle_is_planned_in_pieces(planned) -> None:
    p = planned.program
    rows = np.flatnonzero((p.section == PRINT) & (p.op == MOVEL))
    axes = nozzle_axes(p.quat_wxyz[rows])
    turn = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", axes[1:], axes[:-1]), -1, 1)))
    assert turn.max() <= 5.0 + 1e-6             # max_turn_deg; the G-code's crossing travel turns 60 deg
    assert planned.stats.moves == len([ln for ln in tilted_rings().splitlines() if ln.startswith(("G0", "G1"))])


def test_tilt_deg_is_refused_for_multiaxis_gcode(cell: Cell) -> None:
    with pytest.raises(ValidationError, match="tilt_deg"):
        plan_gcode(tilted_rings(), cell, PlanOptions(tilt_deg=(10.0, 0.0)))


def test_planning_in_chunks_gives_the_whole_plan(cell: Cell) -> None:
    text = tilted_rings(layers=8, n=300)
    whole = plan_gcode(text, cell).program
    chunked = plan_gcode(text, cell, PlanOptions(ik_block_rows=1000)).program
    assert len(chunked) == len(whole)
    np.testing.assert_allclose(chunked.xyz_mm, whole.xyz_mm, atol=1e-9)
    np.testing.assert_allclose(chunked.q_rad, whole.q_rad, atol=1e-9)


def test_the_twin_lays_beads_along_the_nozzle_and_the_check_sees_them_so(planned, cell: Cell) -> None:
    p = planned.program
    twin = Twin(cell)
    twin.load(p)
    twin.start()
    for _ in range(100_000):
        if twin.state not in ("printing", "paused") and not twin.moving:
            break
        twin.advance(1e6)
    beads = twin.beads
    assert len(beads) > 0 and twin.state == "idle"
    ext = np.flatnonzero((p.op == MOVEL) & (p.flow_mm3_mm > 0))
    np.testing.assert_allclose(beads.axis, nozzle_axes(p.quat_wxyz[beads.row]), atol=1e-12)
    assert np.degrees(np.arccos(np.clip(beads.axis[:, 2], -1, 1))).max() == pytest.approx(30.0, abs=1e-3)
    # heights from the flow at the stated width, so every bead's volume is its own
    np.testing.assert_allclose(beads.width_mm, 0.45)
    area = bead_area_mm2(beads.width_mm, beads.height_mm)
    np.testing.assert_allclose(area, p.flow_mm3_mm[beads.row], rtol=1e-9)
    assert beads.total_volume_mm3 == pytest.approx(p.deposited_volume_mm3(), rel=1e-9)
    assert beads.height_mm.min() > 0.25 and beads.height_mm.max() < 0.35
    # a flow more than a round bead of that width holds makes it wider, keeping its volume
    w, h = Deposition(p).dims(np.zeros(2, np.int64), np.array([0.1, 0.5]))
    np.testing.assert_allclose(bead_area_mm2(w, h), [0.1, 0.5])
    assert w[0] == pytest.approx(0.45) and w[1] > 0.45 and h[1] == pytest.approx(0.45)
    mesh = beads.mesh()
    assert mesh.is_watertight and mesh.volume == pytest.approx(beads.total_volume_mm3, rel=1e-9)
    # a tilted bead hangs from the nozzle path along its axis: its lowest point is an octagon corner, below
    # the path by h cos(tilt) + w/2 sin(tilt) less the chamfer (by h for a vertical nozzle)
    last = beads.row == beads.row.max()
    one = Deposition.from_arrays(p, {k: v[last] for k, v in beads.to_arrays().items()})
    lo = one.mesh().bounds[0][2]
    h, w, t = one.height_mm[0], one.width_mm[0], math.radians(30.0)
    top = min(one.start_mm[0, 2], one.end_mm[0, 2])
    c = h * math.sqrt((1 - math.pi / 4) / 2)                  # the octagon's corner legs
    corner = max((h - c) * math.cos(t) + w / 2 * math.sin(t), h * math.cos(t) + (w / 2 - c) * math.sin(t))
    assert top - lo == pytest.approx(corner, rel=0.02)
    # the collision check's boxes are the twin's beads, turned the same way (a proper rotation)
    solids = BeadSolids.from_program(p)
    assert len(solids) == len(ext)
    np.testing.assert_allclose(np.linalg.det(solids.axes), 1.0, atol=1e-9)
    up = solids.axes[:, :, 2]                                  # the box's z: the axis made normal to the move
    base_axes = nozzle_axes(p.quat_wxyz[solids.row]) @ p.wobj[:3, :3].T
    assert np.all(np.einsum("ij,ij->i", up, base_axes) > 0.99)
    # beads saved before multi-axis printing (no axis) load as laid straight up
    old = {k: v for k, v in beads.to_arrays().items() if k != "axis"}
    np.testing.assert_array_equal(Deposition.from_arrays(p, old).axis, np.tile([0.0, 0.0, 1.0], (len(beads), 1)))


def test_a_wrist_jump_suggests_the_multiaxis_cell_only_on_another_cell() -> None:
    """The reason of a tilted program's wrist jump names the cell that can follow the tilt, except to that
    cell itself (there it would send the operator in a circle)."""
    from fabric.motion.testprog import square_program
    from fabric.planning.report import MULTIAXIS_CELL, unreachable_detail

    program = square_program(Cell.builtin("irb140"), size_mm=10, layers=1, layer_height_mm=0.3, speed_mm_s=20)
    program.meta["multiaxis"] = True
    row = len(program) // 2
    program.q_rad[row:, 3] += math.radians(354.0)                 # A4 turns almost a whole turn
    other = unreachable_detail(program, row, "joint jump", "irb140")
    same = unreachable_detail(program, row, "joint jump", MULTIAXIS_CELL)
    assert other.startswith("A4 turns 354 deg")
    assert other.endswith(f"(a cell whose wrist stays bent can: {MULTIAXIS_CELL})")
    assert same.startswith("A4 turns 354 deg") and MULTIAXIS_CELL not in same and "cannot follow the tilt" in same
