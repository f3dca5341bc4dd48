"""The layers a layer rests on: what the nozzle's tip may touch while it lays it.

A curved slicer's top band lies on the ends of the core's layers, so its
first layer rests on many layers, not only on the one printed before it. The
tip riding on them is how it prints; the check must not call it a collision,
and must still call the tip in a layer it does not rest on one
(``test_collision_curved.py``: a tip tilted into the layer two down).
"""
from __future__ import annotations

import numpy as np
import pytest

from fabric.collision.beads import BeadSolids
from fabric.collision.support import resting_layers
from fabric.robot.cell import Cell

from support.certify_cells import plan_reachable

pytestmark = pytest.mark.timeout(300)

LAYER_MM = 0.3
WIDTH_MM = 0.42
CORE_END_MM = {0: 5.0, 1: 3.0, 2: 1.0, 3: -1.0}      # each core layer stops 2 mm short of the one under it
XS = np.arange(-5.0, 5.0 + 1e-9, 0.5)
CENTRE = (125.0, 125.0)


def core_top_mm(x: float) -> float:
    """The top of the core under ``x``: the highest core layer that reaches it."""
    return LAYER_MM * sum(1 for end in CORE_END_MM.values() if x <= end + 1e-9)


def staircase() -> tuple[list[tuple[float, float, float]], list[int]]:
    """Lines along y (x, z of the line's top, layer): four core layers, each shorter than the one under it,
    then a band layer lying on all their ends (its line over x rests on the highest core layer there)."""
    lines = [(x, LAYER_MM * (k + 1), k) for k, end in CORE_END_MM.items() for x in XS if x <= end + 1e-9]
    lines += [(x, core_top_mm(x) + LAYER_MM, 4) for x in XS]
    return [(x, z, 0.0) for x, z, _ in lines], [k for _, _, k in lines]


def staircase_beads() -> BeadSolids:
    rows, layers = staircase()
    start = np.array([[x, -5.0, z] for x, z, _ in rows])
    end = np.array([[x, 5.0, z] for x, z, _ in rows])
    n = len(rows)
    return BeadSolids.from_path(start, end, np.full(n, WIDTH_MM), np.full(n, LAYER_MM), np.array(layers),
                                np.arange(1, n + 1), np.full(n, -1), np.eye(4))


def staircase_gcode() -> str:
    """The staircase as a multi-axis program (nozzle vertical), one serpentine per layer."""
    xc, yc = CENTRE
    flow_mm3_mm = WIDTH_MM * LAYER_MM - (1.0 - np.pi / 4.0) * LAYER_MM ** 2     # a stadium bead as tall as the layer
    e_mm = flow_mm3_mm / (np.pi * 0.875 ** 2)           # filament per mm of bead (1.75 mm: the planner assumes it)
    out = ["; multiaxis: nozzle axis in I J K", "G21", "G90", "M83", "M104 S205", "M109 S205"]
    rows, layers = staircase()
    ijk = "I0 J0 K1"
    for layer in range(5):
        mine = [r for r, k in zip(rows, layers, strict=True) if k == layer]
        out += [";LAYER_CHANGE", f";Z:{mine[0][1]:.3f}", f";HEIGHT:{LAYER_MM:.3f}"]
        for j, (x, z, _) in enumerate(mine):
            ys = (-5.0, 5.0) if j % 2 == 0 else (5.0, -5.0)
            if j == 0:
                out += [f"G0 X{xc + x:.3f} Y{yc + ys[0]:.3f} Z{z + 2.0:.3f} {ijk} F6000", f"G0 Z{z:.3f} {ijk}",
                        ";TYPE:Solid infill", f";WIDTH:{WIDTH_MM:.3f}"]
            else:
                out.append(f"G1 X{xc + x:.3f} Y{yc + ys[0]:.3f} Z{z:.3f} {ijk} E{e_mm * 0.5:.5f} F1200")
            out.append(f"G1 X{xc + x:.3f} Y{yc + ys[1]:.3f} Z{z:.3f} {ijk} E{e_mm * 10.0:.5f} F1200")
        out.append(f"G0 Z{mine[-1][1] + 2.0:.3f} {ijk}")
    return "\n".join(out) + "\n"


def test_each_core_layer_rests_on_the_one_under_and_the_band_on_every_end_it_covers():
    beads = staircase_beads()
    rests = resting_layers(beads.centre, beads.axes, beads.half, beads.layer)
    assert rests == {4: (0, 1, 2)}                             # besides the layer before: given
    assert beads.exempt_layers(4) == (4, 3, 0, 1, 2)
    assert beads.exempt_layers(2) == (2, 1)                     # nothing more where nothing more is under


def test_a_layer_held_above_a_gap_rests_on_nothing_there():
    """A bead whose bottom is a layer above the nearest bead under it does not rest on it."""
    start = np.array([[0.0, -5.0, 0.3], [0.0, -5.0, 0.9]])
    end = np.array([[0.0, 5.0, 0.3], [0.0, 5.0, 0.9]])
    beads = BeadSolids.from_path(start, end, np.full(2, WIDTH_MM), np.full(2, LAYER_MM), np.array([0, 2]),
                                 np.array([1, 2]), np.full(2, -1), np.eye(4))
    assert resting_layers(beads.centre, beads.axes, beads.half, beads.layer) == {}
    assert beads.exempt_layers(2) == (2, 1)


def test_flat_layers_are_not_searched_and_rest_on_the_layer_before_only():
    """Planar printing (one nozzle axis, each layer at one height): nothing older lies right under a layer."""
    beads = staircase_beads()
    flat = beads.layer < 4                                      # the core: flat layers
    core = BeadSolids(beads.centre[flat], beads.axes[flat], beads.half[flat], beads.layer[flat], beads.row[flat],
                      beads.gcode_line[flat])
    assert resting_layers(core.centre, core.axes, core.half, core.layer) == {}
    assert core.exempt_layers(3) == (3, 2)


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140-multiaxis")


def test_the_band_riding_on_the_core_ends_is_not_a_collision(cell, cert):
    """The tip laying the band over layer 1 slides over the end of layer 2 beside it, at its own height: it
    rests on layer 2 a step earlier. The exemption by index alone (the band's layer and the one before) called
    that a collision of the tip with layer 2."""
    program = plan_reachable(cell, staircase_gcode())
    res = cert.sweep_program(program)
    assert res.collision_free, res.first_hit
    assert cert.beads.exempt_layers(4) == (4, 3, 0, 1, 2)
    assert res.clearance_mm > cert.tol
