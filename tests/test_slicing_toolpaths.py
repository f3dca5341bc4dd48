"""Built-in slicer toolpaths: travel inside the part, retractions, island order, bridges, gap fill, seams."""
from __future__ import annotations

import math
import re

import numpy as np
import pytest
import shapely

from fabric.slicing import load_profile, slice_model
from fabric.slicing.builtin.bridges import bridge_angle
from fabric.slicing.builtin.layers import layer_heights, rings_to_polygons, section_rings
from fabric.slicing.builtin.regions import Island, Loop, island_perimeters
from fabric.slicing.builtin.toolpath import order_islands, seam_point
from fabric.slicing.builtin.travel import TravelPlanner, travel_pieces
from fabric.slicing.flow import bead_area_mm2, bead_spacing_mm
from fabric.slicing.gcode_stats import gcode_stats
from fabric.slicing.placement import place_mesh
from fabric.slicing.samples import bridge_part, gear, thin_walls, to_stl_bytes, towers

TAZ = load_profile("taz-pla-medium", {"skirt_loops": "0"})
FILAMENT_MM2 = math.pi * 1.425 ** 2
_MOVE = re.compile(r"^G1 X(-?[\d.]+) Y(-?[\d.]+)(?: E(-?[\d.]+))?")

# a C-shaped island: the straight line between the tips of its arms crosses the notch (open air)
C_SHAPE = shapely.Polygon([(0, 0), (20, 0), (20, 4), (4, 4), (4, 16), (20, 16), (20, 20), (0, 20)])


def _layers(gcode: str) -> list[str]:
    return gcode.split(";LAYER_CHANGE\n")[1:]


def _slices(mesh, profile) -> list[shapely.Geometry]:
    """Every layer's outline of ``mesh`` as the slicer places and cuts it."""
    placed = place_mesh(mesh, None, (250.0, 250.0), 250.0)
    tops, thick = layer_heights(float(placed.bounds[1, 2]), profile.layer_height_mm, profile.first_layer_height_mm)
    xy, start, plane, _ = section_rings(placed, tops - thick / 2.0)
    return rings_to_polygons(xy, start, plane, len(tops))


def _travels(layer_text: str) -> list[tuple[np.ndarray, bool]]:
    """Every travel of a layer as (polyline, retracted before it), a travel being the moves between two beads."""
    out: list[tuple[np.ndarray, bool]] = []
    pos: tuple[float, float] | None = None        # where the nozzle is
    current: list[tuple[float, float]] = []       # the travel under way, from where it started
    retracted = False
    for line in layer_text.splitlines():
        if line.startswith("G1 E-"):
            retracted = True
            continue
        m = _MOVE.match(line)
        if not m:
            continue
        xy = (float(m.group(1)), float(m.group(2)))
        if m.group(3) is None:
            if not current and pos is not None:
                current.append(pos)
            current.append(xy)
        else:
            if len(current) > 1:
                out.append((np.asarray(current), retracted))
            current, retracted = [], False
        pos = xy
    return out


# -- travel planning --------------------------------------------------------------------------------
def test_travel_inside_a_notched_island_goes_round_the_notch_without_retracting() -> None:
    planner = TravelPlanner(travel_pieces(C_SHAPE), min_travel_mm=2.0, inside_max_mm=100.0)
    path, retract = planner.plan((18.0, 2.0), (18.0, 18.0))
    assert not retract
    assert len(path) > 2                                         # not the straight line across the notch
    assert C_SHAPE.covers(shapely.LineString(path))
    assert shapely.LineString(path).length < 2 * 16 + 16          # pulled tight: no wander along every edge
    # a straight move that stays inside is kept straight
    path, retract = planner.plan((2.0, 2.0), (2.0, 18.0))
    assert not retract and len(path) == 2


def test_travel_retracts_into_open_air_or_when_long_inside_never_when_short() -> None:
    two = shapely.union(C_SHAPE, shapely.box(30, 0, 40, 10))
    planner = TravelPlanner(travel_pieces(two), min_travel_mm=2.0, inside_max_mm=30.0)
    assert planner.plan((18.0, 2.0), (35.0, 5.0))[1]              # to another island: crosses air
    assert not planner.plan((31.0, 1.0), (32.0, 2.0))[1]          # short: never
    path, retract = planner.plan((18.0, 2.0), (18.0, 18.0))       # inside but a 40 mm route > 30 mm
    assert retract and len(path) == 2


@pytest.mark.parametrize("make", [gear, towers], ids=["gear", "towers"])
def test_every_unretracted_travel_stays_over_the_part(make) -> None:
    mesh = make()
    res = slice_model(to_stl_bytes(mesh), "part.stl", TAZ)
    slices = _slices(mesh, TAZ)
    inside = outside = 0
    for text, outline in zip(_layers(res.gcode), slices, strict=True):
        region = shapely.buffer(outline, 1e-3)
        for path, retracted in _travels(text):
            line = shapely.LineString(path)
            if retracted or line.length <= TAZ.retract_min_travel_mm:
                continue
            inside += 1
            outside += not region.covers(line)
    assert inside > 100 and outside == 0


def test_gear_retracts_only_to_start_and_end() -> None:
    res = slice_model(to_stl_bytes(gear()), "gear.stl", TAZ)
    # one island per layer: the nozzle never leaves the part, so only the first move and the end retract
    assert res.retractions == 2 == res.gcode.count("\nG1 E-")
    assert res.travel_mm == pytest.approx(gcode_stats(res.gcode, 2.85).travel_mm, rel=1e-3)


def test_towers_retract_once_per_jump_between_islands() -> None:
    res = slice_model(to_stl_bytes(towers()), "towers.stl", TAZ)
    layers = _layers(res.gcode)
    per_layer = [lay.count("G1 E-") for lay in layers]
    assert per_layer[-1] <= 6 and max(per_layer[10:-1]) == 5      # six towers: five jumps (+ the final retract)
    assert res.retractions == sum(per_layer)


def test_island_order_shortens_the_jumps() -> None:
    # five islands on a line, handed over shuffled: visited end to end from the nozzle's side
    xs = [40.0, 0.0, 30.0, 10.0, 20.0]
    islands = [Island(shapely.box(x, 0, x + 4, 4), [Loop(np.asarray([(x, 0), (x + 4, 0), (x + 4, 4), (x, 4)]), 0,
                                                           False)]) for x in xs]
    order = order_islands(islands, (-5.0, 0.0), "nearest")
    assert [float(isl.outline.bounds[0]) for isl in order] == [0.0, 10.0, 20.0, 30.0, 40.0]


# -- bridges ----------------------------------------------------------------------------------------
def test_bridge_over_air_is_found_anchored_and_printed_with_bridge_flow_and_speed() -> None:
    prof = TAZ.replace(bridge_flow_r=0.8, bridge_speed_mm_s=15.0)
    res = slice_model(to_stl_bytes(bridge_part()), "bridge.stl", prof)
    layers = _layers(res.gcode)
    deck = 32                                   # first layer above the 8 mm pillars: 0.3 + 31 x 0.25 = 8.05
    assert "Bridge infill" in layers[deck] and "Bridge infill" not in layers[deck - 1]
    text = layers[deck].split(";TYPE:Bridge infill\n")[1].split(";TYPE:")[0]
    assert "G1 F900" in text                                              # 15 mm/s
    width = float(re.search(r"^;WIDTH:([\d.]+)", text, re.M).group(1))     # solid spacing, stretched to fit
    rows = [(float(x), float(y), float(e or 0)) for x, y, e in re.findall(r"^G1 X([\d.]+) Y([\d.]+)(?: E([\d.]+))?",
                                                                            text, re.M)]
    xy = np.asarray(rows)
    beads = [(xy[k - 1, :2], xy[k, :2], xy[k, 2]) for k in range(1, len(xy)) if xy[k, 2] > 0]
    long = [(a, b, e) for a, b, e in beads if np.hypot(*(b - a)) > 5.0]
    assert len(long) > 10
    for a, b, e in long:
        d = b - a
        assert abs(d[1]) < 1e-3 * abs(d[0]) + 2e-3                      # lines run along X, pillar to pillar
        assert abs(d[0]) > 20.0                                          # span the 20 mm gap
        per_mm = e / np.hypot(*d)
        assert per_mm == pytest.approx(0.8 * bead_area_mm2(width, 0.25) / FILAMENT_MM2, rel=2e-3)
    # reported: the deck's underside between the pillars, plus the anchors and the internal bridge of the top
    span = 20.0 * (12.0 - 2 * 0.6)
    assert res.bridge_area_mm2 > span


def test_bridge_direction_is_the_one_anchored_on_both_sides() -> None:
    anchors = shapely.union(shapely.box(-10, 0, 0, 10), shapely.box(20, 0, 30, 10))
    region = shapely.box(-3, 1, 23, 9)
    assert math.degrees(bridge_angle(region, anchors, 0.37)) % 180.0 == pytest.approx(0.0, abs=1e-6)
    turned = shapely.union(shapely.box(0, -10, 10, 0), shapely.box(0, 20, 10, 30))
    assert math.degrees(bridge_angle(shapely.box(1, -3, 9, 23), turned, 0.37)) == pytest.approx(90.0, abs=1e-6)


# -- gap fill and seams -----------------------------------------------------------------------------
def test_wall_too_thin_for_two_perimeters_gets_gap_fill_and_no_infill() -> None:
    spacing = bead_spacing_mm(0.42, 0.25)
    wall = shapely.box(0, 0, 1.0, 20)                     # 1 mm: the external loops leave 0.214 mm between them
    isl = island_perimeters(wall, 2, 0.42, 0.25, 0.25)
    assert [lp.depth for lp in isl.loops] == [0] and isl.fill.is_empty
    assert len(isl.gaps) == 1
    gap = isl.gaps[0]
    assert np.ptp(gap.xy[:, 0]) < 1e-6 and gap.xy[0, 0] == pytest.approx(0.5)     # along the wall's middle
    assert np.ptp(gap.xy[:, 1]) > 19.0
    thick = 1.0 - 0.42 - spacing                          # what is left between the two beads
    assert np.median(gap.widths_mm) == pytest.approx(thick + 0.25 * (1 - math.pi / 4), abs=2e-3)
    # walls a loop fills (0.6 mm) or that take two loops (1.5 mm) get none
    assert island_perimeters(shapely.box(0, 0, 0.6, 20), 2, 0.42, 0.25, 0.25).gaps == []
    assert island_perimeters(shapely.box(0, 0, 1.5, 20), 2, 0.42, 0.25, 0.25).gaps == []


def test_thin_walls_part_prints_gap_fill_on_every_wall_layer() -> None:
    res = slice_model(to_stl_bytes(thin_walls()), "walls.stl", TAZ)
    layers = _layers(res.gcode)
    assert all(lay.count(";TYPE:Gap fill") == 1 for lay in layers[6:])      # the 1 mm wall, above the base
    # one bead of about 23 mm per layer filling 0.214 mm x 0.25 mm
    per_layer = gcode_stats(res.gcode, 2.85).volume_by_type_mm3["Gap fill"] / len(layers[6:])
    assert per_layer == pytest.approx(23.2 * 0.214 * 0.25, rel=0.05)


def test_seam_hides_in_a_notch_and_stays_aligned() -> None:
    # an L whose notch faces the rear right: the notch's corner beats the convex corners beside it
    ell = Loop(np.asarray([(0, 0), (10, 0), (10, 6), (6, 6), (6, 10), (0, 10)], dtype=float), 0, False)
    assert seam_point(ell, "aligned", (0.0, 0.0)) == (6.0, 6.0)
    assert seam_point(ell, "nearest", (10.0, 7.0)) == (10.0, 6.0)                   # too far from the nozzle
    assert seam_point(ell, "nearest", (8.0, 7.5)) == (6.0, 6.0)
    square = Loop(np.asarray([(0, 0), (10, 0), (10, 10), (0, 10)], dtype=float), 0, False)
    assert seam_point(square, "aligned", (0.0, 0.0)) == (10.0, 10.0)                 # no notch: rear right
    res = slice_model(to_stl_bytes(gear()), "gear.stl", TAZ)
    seams = []
    for lay in _layers(res.gcode)[4:-5]:
        before = lay.split(";TYPE:External perimeter")[0]
        seams.append([float(v) for v in re.findall(r"^G1 X(-?[\d.]+) Y(-?[\d.]+)", before, re.M)[-1]])
    assert np.ptp(np.asarray(seams), axis=0).max() < 1e-6                          # aligned up the part
    r = math.hypot(seams[0][0] - 125.0, seams[0][1] - 125.0)
    assert r < 17.0 + 0.1                                                           # at a tooth root, not a tip
