"""The built-in slicer: sectioning, bead model, G-code conventions, shells, seams, travel, progress."""
from __future__ import annotations

import itertools
import math
import re

import numpy as np
import pytest
import shapely

from fabric.slicing import load_profile, slice_model
from fabric.slicing.builtin.layers import (
    layer_heights,
    rings_to_polygons,
    section_rings,
)
from fabric.slicing.builtin.regions import Loop
from fabric.slicing.builtin.toolpath import loop_path
from fabric.slicing.flow import bead_area_mm2, bead_spacing_mm
from fabric.slicing.gcode_stats import gcode_stats
from fabric.slicing.samples import box, cylinder, islands_part, to_stl_bytes

BOX = to_stl_bytes(box((20.0, 20.0, 10.0)))
CYL = to_stl_bytes(cylinder(10.0, 10.0))
ISLANDS = to_stl_bytes(islands_part())
TAZ = load_profile("taz-pla-medium", {"skirt_loops": "0"})
_MOVE = re.compile(r"^G1 X(-?[\d.]+) Y(-?[\d.]+)(?: E(-?[\d.]+))?", re.M)


def _layers(gcode: str) -> list[str]:
    """The G-code of each layer (text after each ;LAYER_CHANGE)."""
    return gcode.split(";LAYER_CHANGE\n")[1:]


def _moves(text: str) -> np.ndarray:
    """(x, y, e) of every XY move, e = 0 for travels."""
    rows = [(float(x), float(y), float(e) if e else 0.0) for x, y, e in _MOVE.findall(text)]
    return np.asarray(rows).reshape(-1, 3)


def _paths(text: str) -> list[tuple[str, int]]:
    """(feature type, number of moves) of every continuous extrusion path."""
    out: list[tuple[str, int]] = []
    kind, run = "", 0
    for line in text.splitlines():
        if line.startswith(";TYPE:"):
            kind = line[6:]
        m = _MOVE.match(line)
        if m and m.group(3):
            run += 1
        elif m and run:
            out.append((kind, run))
            run = 0
    if run:
        out.append((kind, run))
    return out


@pytest.fixture(scope="module")
def box_result():
    return slice_model(BOX, "box.stl", TAZ)


def test_layer_heights_follow_prusaslicer() -> None:
    tops, thick = layer_heights(10.0, 0.25, 0.3)
    assert len(tops) == 40 and thick[0] == 0.3 and (thick[1:] == 0.25).all()
    assert tops[-1] == pytest.approx(10.05)         # last layer: mid-height 9.925 < 10
    # accumulated by repeated addition: 0.7 + 15 x 0.6 lands just under 9.7 -> a 17th layer
    assert len(layer_heights(10.0, 0.6, 0.7)[0]) == 17


def test_section_finds_islands_holes_and_orientation() -> None:
    mesh = islands_part()
    planes = np.array([1.0, 4.0, 7.9])
    xy, start, plane, open_chains = section_rings(mesh, planes)
    assert open_chains == 0
    polys = rings_to_polygons(xy, start, plane, len(planes))
    for geom in polys:
        parts = sorted(shapely.get_parts(geom), key=lambda g: g.centroid.x)
        assert [len(p.interiors) for p in parts] == [1, 1, 0]       # tube, block with hole, pin
        expected = (math.pi * (25 - 6.25), 8 * 12 - 16, math.pi * 9)
        assert [p.area for p in parts] == pytest.approx(expected, rel=0.01)


def test_bead_model_is_the_slic3r_rounded_rectangle() -> None:
    w, h = 0.42, 0.25
    assert bead_area_mm2(w, h) == pytest.approx((w - h) * h + math.pi * (h / 2) ** 2)
    assert bead_spacing_mm(w, h) * h == pytest.approx(bead_area_mm2(w, h))


def test_e_of_every_perimeter_move_is_length_times_bead_area(box_result) -> None:
    first = _layers(box_result.gcode)[0]
    ext = first.split(";TYPE:External perimeter\n")[1].split(";TYPE:")[0]
    start = _moves(first.split(";TYPE:External perimeter\n")[0])[-1, :2]
    pts = _moves(ext)
    pts = pts[: np.argmin(pts[:, 2] > 0)]               # up to the travel that ends the loop
    assert len(pts) == 4
    seg = np.linalg.norm(np.diff(np.vstack([start, pts[:, :2]]), axis=0), axis=1)
    e_mm = seg * bead_area_mm2(0.42, 0.3) / (math.pi * 1.425 ** 2)
    assert pts[:, 2] == pytest.approx(e_mm, abs=2e-5)


def test_gcode_conventions(box_result) -> None:
    g = box_result.gcode
    assert "G28" not in g and "M84" not in g
    head = g.split(";LAYER_CHANGE")[0]
    for code in ("M140 S60", "M104 S205", "M190 S60", "M109 S205", "M83", "G92 E0"):
        assert code in head
    assert g.count(";LAYER_CHANGE") == box_result.layers == 40
    z = [float(v) for v in re.findall(r"^;Z:([\d.]+)", g, re.M)]
    assert z == pytest.approx(list(layer_heights(10.0, 0.25, 0.3)[0]))
    xy = _moves(g)
    assert xy[:, 0].min() >= 115.0 and xy[:, 0].max() <= 135.0       # placed at the plate centre
    assert xy[:, 1].min() >= 115.0 and xy[:, 1].max() <= 135.0
    assert box_result.bbox_mm == [[115.0, 115.0, 0.0], [135.0, 135.0, 10.0]]
    stats = gcode_stats(g, 2.85)
    assert stats.extruded_mm3 == pytest.approx(box_result.extruded_mm3, rel=1e-4)


def test_top_and_bottom_layers_are_solid_the_middle_sparse(box_result) -> None:
    layers = _layers(box_result.gcode)
    solid = ["Solid infill" in lay or "Top solid infill" in lay or "Bridge infill" in lay for lay in layers]
    sparse = ["Internal infill" in lay for lay in layers]
    assert solid[:3] == [True] * 3 and solid[-4:] == [True] * 4          # 3 bottom, 4 top layers
    assert not any(solid[3:-4]) and all(sparse[3:-4]) and not any(sparse[:3] + sparse[-4:])
    assert "Top solid infill" in layers[-1]
    # the first solid layer over the sparse infill bridges it (PrusaSlicer's internal bridge); only that one
    assert ["Bridge infill" in lay for lay in layers] == [i == len(layers) - 4 for i in range(len(layers))]


def test_full_infill_fills_the_model_and_density_orders_volume() -> None:
    vols = [slice_model(BOX, "b.stl", TAZ.replace(infill_density_r=d)).extruded_mm3 for d in (0.0, 0.2, 1.0)]
    assert vols[0] < vols[1] < vols[2]
    assert vols[2] == pytest.approx(4000.0, rel=0.03)      # 100 %: the beads fill the part


def test_islands_and_holes_each_get_their_perimeters() -> None:
    res = slice_model(ISLANDS, "i.stl", TAZ)
    mid = _layers(res.gcode)[len(_layers(res.gcode)) // 2]
    paths = _paths(mid)
    # 3 outlines + 2 holes, each with an external and an inner perimeter
    assert sum(k == "External perimeter" for k, _ in paths) == 5
    assert sum(k == "Perimeter" for k, _ in paths) == 5


def test_aligned_seam_stays_put_nearest_follows_the_nozzle() -> None:
    def seams(res) -> np.ndarray:
        out = []
        for lay in _layers(res.gcode)[3:-4]:
            before = lay.split(";TYPE:External perimeter")[0]
            out.append(_moves(before)[-1, :2])
        return np.asarray(out)

    aligned = seams(slice_model(CYL, "c.stl", TAZ))
    assert np.ptp(aligned, axis=0).max() < 1e-6
    loop = Loop(np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]), 0, False)
    path = loop_path(loop, (9.0, 11.0), clip_mm=0.5)
    assert path[0] == pytest.approx([10.0, 10.0])                      # vertex nearest the seam point
    assert np.linalg.norm(path[-1] - path[0]) == pytest.approx(0.5)    # clipped before closing


def test_long_travel_retracts_short_does_not() -> None:
    res = slice_model(ISLANDS, "i.stl", TAZ)
    lines = res.gcode.splitlines()
    retracts = [i for i, ln in enumerate(lines) if ln.startswith("G1 E-1.00000")]
    assert len(retracts) > 1
    assert lines[retracts[-1] + 1] == ";TYPE:Custom"     # the last one ends the print
    for i in retracts[:-1]:                             # retract, travel(s), de-retract
        j = next(k for k in range(i + 1, len(lines)) if " E" in lines[k] or lines[k].startswith("G1 E"))
        assert lines[j].startswith("G1 E1.00000")
    no_retract = slice_model(ISLANDS, "i.stl", TAZ.replace(retract_min_travel_mm=1000.0))
    printing = no_retract.gcode.split(";TYPE:", 2)[2].rsplit(";TYPE:Custom", 1)[0]   # after the first bead
    assert printing.count("G1 E-") == 1 and printing.rstrip().endswith("G1 E-1.00000 F1500")  # only at the end


def test_progress_is_monotonic_from_zero_to_one() -> None:
    seen: list[float] = []
    slice_model(ISLANDS, "i.stl", TAZ, progress=seen.append)
    assert seen[0] == 0.0 and seen[-1] == 1.0 and len(seen) > 4
    assert all(b >= a for a, b in itertools.pairwise(seen))


def test_skirt_on_first_layer_only() -> None:
    res = slice_model(BOX, "b.stl", TAZ.replace(skirt_loops=2, skirt_distance_mm=5.0))
    layers = _layers(res.gcode)
    assert layers[0].count(";TYPE:Skirt/Brim") == 1 and all("Skirt" not in lay for lay in layers[1:])
    skirt = _moves(layers[0].split(";TYPE:Skirt/Brim")[1].split(";TYPE:")[0])
    skirt = skirt[skirt[:, 2] > 0]
    outside = np.maximum(np.abs(skirt[:, :2] - 125.0) - 10.0, 0.0)     # distance to the 20 mm box
    dist = np.hypot(outside[:, 0], outside[:, 1])
    assert dist.min() == pytest.approx(5.0 + 0.21, abs=0.01)                   # inner loop
    assert dist.max() == pytest.approx(5.21 + bead_spacing_mm(0.42, 0.3), abs=0.01)   # second loop


def test_grid_lays_both_directions_on_one_layer() -> None:
    res = slice_model(BOX, "b.stl", TAZ.replace(infill_pattern="grid"))
    mid = _layers(res.gcode)[20].split(";TYPE:Internal infill")[1]
    xy = _moves(mid)
    ext = np.flatnonzero(xy[:, 2] > 0)
    ext = ext[ext > 0]
    d = xy[ext, :2] - xy[ext - 1, :2]
    angles = np.round(np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 180.0)
    assert set(angles) == {45.0, 135.0}


def test_slice_result_figures(box_result) -> None:
    assert box_result.backend == "builtin" and box_result.faces == 12
    assert box_result.model_volume_mm3 == pytest.approx(4000.0)
    assert box_result.filament_mm * math.pi * 1.425 ** 2 == pytest.approx(box_result.extruded_mm3)
    assert box_result.elapsed_s > 0 and box_result.warnings == []


def test_part_thinner_than_a_bead_is_refused() -> None:
    from fabric.wire.errors import MeshError
    with pytest.raises(MeshError, match="nothing to print") as err:
        slice_model(to_stl_bytes(box((0.3, 0.3, 0.3))), "speck.stl", TAZ)
    assert err.value.details["reason"] == "too-small"
