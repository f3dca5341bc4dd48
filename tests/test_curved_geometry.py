"""The curved slicer's parts on their own: meshing, heat distance, level sets, tilt limit, typed errors."""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import trimesh
from shapely.geometry import Polygon

from fabric.slicing.backends import slice_model
from fabric.slicing.curved.field import limit_tilt
from fabric.slicing.curved.gcode import _MOVE, _format_moves
from fabric.slicing.curved.heat import _conjugate_gradients, fem_operators, geodesic_distance
from fabric.slicing.curved.isosurface import (
    Surface,
    _chain,
    _chain_walk,
    boundary_loops,
    clip_surface,
    iso_lines,
    iso_lines_many,
    iso_surface,
)
from fabric.slicing.curved.options import CurvedOptions, thickness_bounds
from fabric.slicing.curved.shapes import dome, extrude_xz
from fabric.slicing.curved.tetmesh import KEEP_AWAY_R, SURFACE_TOLERANCE_MM, _lattice, lattice_pitch_mm, tetrahedralise
from fabric.slicing.profile import load_profile
from fabric.wire.errors import BadRequest, MeshError

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def box_tets():
    box = trimesh.creation.box((20.0, 10.0, 8.0))
    box.apply_translation([0.0, 0.0, 4.0])
    return box, tetrahedralise(box, interior_nodes=3000)


def test_tetrahedralisation_fills_the_part_and_keeps_its_vertices(box_tets):
    box, mesh = box_tets
    p = mesh.nodes[mesh.tets]
    volume = np.linalg.det(p[:, 1:] - p[:, :1]).sum() / 6.0
    assert volume == pytest.approx(box.volume, rel=1e-9)
    surface = {tuple(p) for p in mesh.nodes[:mesh.n_surface].tolist()}
    assert all(tuple(v) in surface for v in box.vertices.tolist()), "a corner of the box moved"
    faces, normals = mesh.boundary_faces()
    areas = 0.5 * np.linalg.norm(np.cross(*(mesh.nodes[faces][:, k] - mesh.nodes[faces][:, 0] for k in (1, 2))),
                                 axis=1)
    assert areas.sum() == pytest.approx(box.area, rel=1e-9)
    outward = np.einsum("ij,ij->i", normals, mesh.nodes[faces].mean(axis=1) - [0.0, 0.0, 4.0])
    assert np.all(outward > 0)


@pytest.mark.parametrize("time_r", [0.0, 1.0], ids=["edge paths", "heat"])
def test_distance_from_the_base_of_a_box_is_its_height(box_tets, time_r):
    _box, mesh = box_tets
    ops = fem_operators(mesh)
    base = np.flatnonzero(mesh.nodes[:, 2] < 1e-9)
    d = geodesic_distance(mesh, ops, base, time_r)
    err = np.abs(d - mesh.nodes[:, 2])
    assert err.max() < 0.1 * 8.0 and err.mean() < 0.02 * 8.0


def test_the_distance_from_the_plate_under_a_dome_is_the_height():
    """Under a dome every point sees the base straight down, so the distance is z. The heat method's
    no-flux walls flatten it under the top; the edge paths must keep it within a few per cent, which is
    what keeps the layers' thickness even (thickness = step / |grad d|)."""
    part = dome()
    mesh = tetrahedralise(part)
    ops = fem_operators(mesh)
    d = geodesic_distance(mesh, ops, np.flatnonzero(mesh.nodes[:, 2] < 1e-9))
    err = np.abs(d - mesh.nodes[:, 2])
    assert err.mean() < 0.01 * 12.0 and err.max() < 0.04 * 12.0, (err.mean(), err.max())


def test_distance_goes_round_a_wall_not_through_it():
    # a U standing on its bottom: two posts joined by a 4 mm bridge at the bottom, 4 mm deep
    u = extrude_xz(Polygon([(-10, 0), (10, 0), (10, 20), (6, 20), (6, 4), (-6, 4), (-6, 20), (-10, 20)]), 4.0)
    mesh = tetrahedralise(u, interior_nodes=4000)
    ops = fem_operators(mesh)
    src = np.flatnonzero((mesh.nodes[:, 2] > 19.99) & (mesh.nodes[:, 0] < -6.0 + 1e-6))     # top of the left post
    d = geodesic_distance(mesh, ops, src)
    far = (mesh.nodes[:, 2] > 19.99) & (mesh.nodes[:, 0] > 6.0 - 1e-6)
    assert d[far].mean() > 35.0      # down 16, across 12, up 16 (inside corners cut); straight: 12 to 20


def test_iso_surface_of_a_linear_field_is_the_plane_section(box_tets):
    _box, mesh = box_tets
    attrs = mesh.nodes.copy()
    s = iso_surface(mesh.tets, mesh.nodes[:, 2], 3.3, attrs)
    assert np.allclose(s.points[:, 2], 3.3)
    tri = s.points[s.tris]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    assert area == pytest.approx(200.0, rel=1e-9)
    loops = boundary_loops(s)
    assert len(loops) == 1 and loops[0][1]
    perimeter = np.linalg.norm(np.diff(np.vstack([loops[0][0], loops[0][0][:1]]), axis=0), axis=1).sum()
    assert perimeter == pytest.approx(60.0, rel=1e-9)
    # clipping keeps x >= 2 (a 8 x 10 rectangle), and the iso-line x = 5 runs across it, 10 mm long
    half = clip_surface(s, 0, 2.0)
    tri = half.points[half.tris]
    assert 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum() == \
        pytest.approx(80.0, rel=1e-9)
    lines = iso_lines(half, half.points[:, 0], 5.0)
    assert len(lines) == 1 and not lines[0][1]
    assert np.linalg.norm(np.diff(lines[0][0][:, :3], axis=0), axis=1).sum() == pytest.approx(10.0, rel=1e-9)


def test_many_levels_at_once_are_the_levels_one_by_one(box_tets):
    _box, mesh = box_tets
    s = iso_surface(mesh.tets, mesh.nodes[:, 2] + 0.1 * mesh.nodes[:, 0], 4.0, mesh.nodes.copy())
    coord = s.points[:, 0] * 0.6 + s.points[:, 1] * 0.8
    levels = np.arange(-9.5, 10.0, 0.7)
    many = iso_lines_many(s, coord, levels)
    assert sum(len(lines) for lines in many) >= 20
    for level, lines in zip(levels, many, strict=True):
        one = iso_lines(s, coord, float(level))
        key = sorted((round(float(np.linalg.norm(np.diff(r[:, :3], axis=0), axis=1).sum()), 9), c) for r, c in lines)
        assert key == sorted((round(float(np.linalg.norm(np.diff(r[:, :3], axis=0), axis=1).sum()), 9), c)
                             for r, c in one)
        for rows, _closed in lines:
            assert np.allclose(rows[:, 0] * 0.6 + rows[:, 1] * 0.8, level)


def _canonical(ids: list[int], closed: bool) -> tuple:
    if closed:
        turns = [ids[i:] + ids[:i] for i in range(len(ids))]
        turns += [t[::-1] for t in turns]
        return ("loop", min(tuple(t) for t in turns))
    return ("line", min(tuple(ids), tuple(ids[::-1])))


def test_chaining_finds_every_line_and_loop_in_any_order():
    rng = np.random.default_rng(7)
    for _trial in range(30):
        chains, segments, start = [], [], 0
        for _c in range(int(rng.integers(1, 25))):
            n = int(rng.integers(2, 30))
            closed = bool(rng.random() < 0.4) and n >= 3
            ids = list(range(start, start + n))
            start += n
            segments += list(itertools.pairwise(ids)) + ([(ids[-1], ids[0])] if closed else [])
            chains.append((ids, closed))
        relabel = rng.permutation(start)
        seg = relabel[np.array(segments)]
        seg = seg[rng.permutation(len(seg))]
        flip = rng.random(len(seg)) < 0.5
        seg[flip] = seg[flip][:, ::-1]
        want = sorted(_canonical([int(relabel[i]) for i in ids], closed) for ids, closed in chains)
        got = sorted(_canonical(ids.tolist(), closed) for ids, closed in _chain(seg))
        assert got == want
        walked = _chain_walk(seg, np.bincount(seg.ravel()))
        assert sorted(_canonical(ids.tolist(), closed) for ids, closed in walked) == want
    # two loops touching at a vertex (more than two segments there): walked, every segment used once
    bow = np.array([[0, 1], [1, 2], [2, 0], [0, 3], [3, 4], [4, 0]])
    out = _chain(bow)
    assert sum(len(ids) - (0 if closed else 1) for ids, closed in out) == len(bow)


def test_moves_are_written_exactly_as_the_format_string_writes_them():
    rng = np.random.default_rng(3)
    rows = np.column_stack([rng.uniform(-5.0, 250.0, (2000, 3)), rng.uniform(-1.0, 1.0, (2000, 3)),
                            rng.uniform(0.0, 0.2, 2000)])
    rows[:6, 3] = [-0.0, 0.0, -1e-7, 1e-7, 0.99999, -0.99996]
    rows[6, :3] = [9.9996, 99.9995, 0.0004]
    assert _format_moves(rows) == [_MOVE.format(*row) for row in rows.tolist()]


def test_conjugate_gradients_solve_the_reduced_stiffness_system(box_tets):
    _box, mesh = box_tets
    ops = fem_operators(mesh)
    free = mesh.nodes[:, 2] > 1e-9
    a = ops.stiffness[free][:, free].tocsr()
    b = np.random.default_rng(1).normal(size=a.shape[0])
    x = _conjugate_gradients(a, b, np.zeros_like(b))
    assert np.linalg.norm(a @ x - b) <= 1e-7 * np.linalg.norm(b)


def test_the_lattice_fills_the_inside_and_keeps_off_the_walls():
    u = extrude_xz(Polygon([(-10, 0), (10, 0), (10, 20), (6, 20), (6, 4), (-6, 4), (-6, 20), (-10, 20)]), 4.0)
    pitch = lattice_pitch_mm(float(u.volume), 3000)
    pts = _lattice(u, pitch)
    x, y, z = pts.T
    inside = (np.abs(y) < 2.0) & (z > 0.0) & (np.abs(x) < 10.0) & ((z < 4.0) | (np.abs(x) > 6.0)) & (z < 20.0)
    assert inside.all(), "a lattice point outside the part"
    assert len(pts) > 0.5 * 2.0 * u.volume / pitch ** 3 * 0.3
    gap = np.minimum.reduce([2.0 - np.abs(y), z, 10.0 - np.abs(x), 20.0 - z,
                             np.where(z > 4.0, np.abs(np.abs(x) - 6.0), np.inf), np.where(np.abs(x) < 6.0, 4.0 - z,
                                                                                         np.inf)])
    assert gap.min() >= KEEP_AWAY_R * pitch / math.sqrt(3.0) - 1e-9


def test_a_100k_triangle_part_gets_a_volume_mesh_of_its_shape_not_of_its_triangles():
    """The speed of the curved slicer hangs on this: the 100k-triangle dome of the benchmark is meshed from
    its surface simplified within the tolerance, not from its 100k triangles (which gave 150k nodes and
    441k tetrahedra, 20 s of TetGen); the surface stays within the tolerance of the sphere."""
    part = dome(radius_mm=40.0, height_mm=25.0, rings=250, sections=200)
    assert len(part.faces) == 100_000
    mesh = tetrahedralise(part)
    assert len(mesh.nodes) < 40_000 and len(mesh.tets) < 200_000, (len(mesh.nodes), len(mesh.tets))
    assert mesh.surface_error_mm == SURFACE_TOLERANCE_MM
    p = mesh.nodes[mesh.tets]
    volume = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]).sum() / 6.0
    assert volume == pytest.approx(part.volume, rel=1e-3)
    sphere_r = (40.0 ** 2 + 25.0 ** 2) / 50.0
    faces, _normals = mesh.boundary_faces()
    on_cap = mesh.nodes[np.unique(faces.ravel())]
    on_cap = on_cap[on_cap[:, 2] > 1e-9]
    off = np.abs(np.linalg.norm(on_cap - [0.0, 0.0, 25.0 - sphere_r], axis=1) - sphere_r)
    assert off.max() <= SURFACE_TOLERANCE_MM + 1e-6


def test_empty_level_sets_are_empty():
    s = Surface(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    assert iso_lines(s, np.zeros(0), 1.0) == [] and boundary_loops(s) == []


def test_tilt_is_limited_in_the_axis_vertical_plane():
    axes = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0], [1.0, 1.0, -1.0]])
    out = limit_tilt(axes, 30.0)
    tilt = np.degrees(np.arccos(out[:, 2]))
    assert np.allclose(tilt, [30.0, 30.0, 0.0, 30.0])
    assert np.allclose(out[1, :2] / np.linalg.norm(out[1, :2]), [0.0, 1.0])
    assert np.allclose(out[3, :2] / np.linalg.norm(out[3, :2]), [math.sqrt(0.5)] * 2)


def test_thickness_bounds_keep_the_ratio_within_six():
    for name in ("taz-pla-medium", "robot-1.2mm"):
        b = thickness_bounds(load_profile(name))
        assert b.min_mm <= b.nominal_mm <= b.max_mm and b.max_mm / b.min_mm <= 6.0 + 1e-9


def test_options_are_range_checked():
    with pytest.raises(BadRequest):
        CurvedOptions(max_tilt_deg=95.0)
    with pytest.raises(BadRequest):
        CurvedOptions(top_band_layers=-1)
    for key, bad in (("tip_radius_mm", -1.0), ("plate_blend_mm", float("nan")), ("max_axis_deviation_deg", 91.0),
                     ("path_axis_window_mm", float("inf")), ("crease_flatten_r", 1.5), ("crease_width_mm", -1.0),
                     ("nozzle_tip_radius_mm", float("nan")), ("nozzle_taper_mm", -3.0), ("nozzle_reach_mm", 1e6)):
        with pytest.raises(BadRequest, match=key):
            CurvedOptions(**{key: bad})


def test_a_mesh_with_a_hole_is_a_typed_error():
    open_box = trimesh.creation.box((10.0, 10.0, 10.0))
    open_box.update_faces(np.arange(len(open_box.faces)) != 0)
    with pytest.raises(MeshError) as err:
        tetrahedralise(open_box)
    assert err.value.details["reason"] == "not_watertight"


def test_curved_layers_refuse_an_external_backend_and_unknown_modes():
    model = trimesh.creation.box((10.0, 10.0, 5.0)).export(file_type="stl")
    profile = load_profile("taz-pla-medium")
    with pytest.raises(BadRequest):
        slice_model(model, "box.stl", profile, backend="prusaslicer", layers="curved")
    with pytest.raises(BadRequest):
        slice_model(model, "box.stl", profile, layers="wavy")


def test_slice_model_runs_the_curved_slicer_end_to_end():
    model = trimesh.creation.box((12.0, 12.0, 4.0)).export(file_type="stl")
    res = slice_model(model, "box.stl", load_profile("taz-pla-medium"), layers="curved")
    assert res.gcode.startswith("; multiaxis: nozzle axis in I J K")
    assert res.layers >= 10 and res.extruded_mm3 > 0.5 * 12 * 12 * 4 * 0.2


def test_a_self_intersecting_solid_is_a_typed_error(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    a = trimesh.creation.box((10.0, 10.0, 10.0))
    b = trimesh.creation.box((10.0, 10.0, 10.0))
    b.apply_translation([5.0, 5.0, 5.0])
    with pytest.raises(MeshError) as err:
        tetrahedralise(trimesh.util.concatenate([a, b]))       # two closed boxes overlapping
    assert err.value.details["reason"] == "tetgen"
    assert list(tmp_path.iterdir()) == [], "TetGen's dump of the offending faces is left behind"
