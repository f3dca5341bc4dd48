"""Curved-layer slicing of the generated shapes: the figures issue 21 asks for, measured on each."""
from __future__ import annotations

import re

import numpy as np
import pytest

from fabric.gcode.reader import parse_gcode
from fabric.slicing.curved import MULTIAXIS_HEADER, CurvedSlice, slice_curved, thickness_bounds
from fabric.slicing.curved.options import MAX_THICKNESS_RATIO
from fabric.slicing.curved.shapes import SHAPES
from fabric.slicing.profile import load_profile

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow]    # slow: slicing the shapes takes 14 s (not the fast tier)

PROFILE = load_profile("taz-pla-medium")
MOVE = re.compile(r"^G1 X(\S+) Y(\S+) Z(\S+) I(\S+) J(\S+) K(\S+) E(\S+)")


@pytest.fixture(scope="module")
def sliced() -> dict[str, CurvedSlice]:
    return {name: slice_curved(make(), PROFILE) for name, make in SHAPES.items()}


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_every_shape_slices_into_curved_layers(sliced, name):
    out = sliced[name]
    assert out.layers >= 10 and out.extruded_mm3 > 0
    assert all(layer for layer in out.paths), "a layer without toolpaths"
    # the deposited volume is the part's volume within a loose margin (sparse infill prints less)
    volume = SHAPES[name]().volume
    assert 0.2 * volume < out.extruded_mm3 < 1.3 * volume


@pytest.mark.parametrize("name", ["frustum", "arch"])
def test_overhang_area_is_at_least_90_percent_below_planar(sliced, name):
    r = sliced[name].report
    assert r.planar_overhang_mm2 > 50.0, "the shape must overhang when sliced flat"
    assert r.overhang_mm2 <= 0.1 * r.planar_overhang_mm2, r


@pytest.mark.parametrize("name", ["dome", "wing"])
def test_last_layers_follow_the_top_with_less_staircase_than_planar(sliced, name):
    r = sliced[name].report
    assert r.planar_cusp_mean_mm > 0.1
    assert r.cusp_mean_mm < 0.5 * r.planar_cusp_mean_mm, r


@pytest.mark.parametrize("name", ["dome", "wing"])
def test_the_largest_staircase_on_the_top_is_no_larger_than_planar(sliced, name):
    """Core layers are thinned where they cut an upward face at a slope (their staircase stays under planar
    layers' on the same face); the band follows the top itself. Planar's largest is its nominal layer on a
    near-flat face, or its thicker first layer on a face near the plate (the wing's trailing edge). The curved
    slice's first layer is planar too (the nozzle is vertical on the plate), so its largest stays under the
    first layer's thickness."""
    r = sliced[name].report
    assert r.planar_cusp_max_mm > 0.2
    assert r.cusp_max_mm <= r.planar_cusp_max_mm, r
    assert r.cusp_max_mm < PROFILE.first_layer_height_mm, r


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_thickness_tilt_and_neighbour_angles_stay_in_bounds(sliced, name):
    r = sliced[name].report
    bounds = thickness_bounds(PROFILE)
    assert r.thickness_ratio_r <= MAX_THICKNESS_RATIO, r
    assert bounds.min_mm - 1e-9 <= r.thickness_min_mm and r.thickness_max_mm <= bounds.max_mm + 1e-9, r
    # the one note allowed: a few points where the nozzle's reach found no clear axis (the arch's crown: 7 of
    # 91k; the collision check of the planned program finds it clear)
    other = [w for w in sliced[name].warnings if "no nozzle axis clears" not in w]
    assert other == []
    for w in sliced[name].warnings:
        blocked, checked = (int(v) for v in re.search(r"at (\d+) of (\d+) points", w).groups())
        assert blocked <= 1e-3 * checked, w
    assert r.max_tilt_deg <= 45.0 + 1e-6
    assert r.max_neighbour_deg <= 45.0 and r.max_field_neighbour_deg <= 45.0, r
    for layer in sliced[name].paths:
        for path in layer:
            assert np.allclose(np.linalg.norm(path.axes, axis=1), 1.0, atol=1e-9)


@pytest.mark.parametrize("name", ["arch", "dome"])
def test_every_extruding_move_carries_a_unit_nozzle_axis(sliced, name):
    text = sliced[name].gcode
    assert text.startswith(f"; {MULTIAXIS_HEADER}\n")
    extruding = [ln for ln in text.splitlines() if ln.startswith("G1 ") and " E" in ln and " X" in ln]
    assert len(extruding) > 1000
    axes = []
    for line in extruding:
        m = MOVE.match(line)
        assert m, f"an extruding move without I J K: {line}"
        axes.append([float(m.group(k)) for k in (4, 5, 6)])
    a = np.array(axes)
    assert np.allclose(np.linalg.norm(a, axis=1), 1.0, atol=2e-4)
    assert a[:, 2].min() >= np.cos(np.radians(45.0)) - 1e-3
    tilted = np.degrees(np.arccos(np.clip(a[:, 2], -1, 1)))
    assert tilted.max() > 5.0, "the nozzle never tilts: the axis is not carried through"


def test_the_gcode_reader_reads_the_dialect_with_its_nozzle_axes(sliced):
    """The reader takes the dialect from its first line: every move keeps its nozzle axis, layer by layer."""
    out = sliced["arch"]
    tp = parse_gcode(out.gcode)
    assert tp.multiaxis and tp.n_layers == out.layers
    assert tp.axis is not None and np.allclose(np.linalg.norm(tp.axis, axis=1), 1.0, atol=2e-4)
    assert np.degrees(np.arccos(np.clip(tp.axis[:, 2], -1.0, 1.0))).max() > 5.0
