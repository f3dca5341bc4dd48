"""The curved slicer's parts on their own: meshing, heat distance, level sets, tilt limit, typed errors."""
from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from shapely.geometry import Polygon

from fabric.slicing.backends import slice_model
from fabric.slicing.curved.field import limit_tilt
from fabric.slicing.curved.heat import fem_operators, heat_distance
from fabric.slicing.curved.isosurface import Surface, boundary_loops, clip_surface, iso_lines, iso_surface
from fabric.slicing.curved.options import CurvedOptions, thickness_bounds
from fabric.slicing.curved.shapes import extrude_xz
from fabric.slicing.curved.tetmesh import tetrahedralise
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
    assert np.allclose(mesh.nodes[:mesh.n_surface], box.vertices)
    faces, normals = mesh.boundary_faces()
    areas = 0.5 * np.linalg.norm(np.cross(*(mesh.nodes[faces][:, k] - mesh.nodes[faces][:, 0] for k in (1, 2))),
                                 axis=1)
    assert areas.sum() == pytest.approx(box.area, rel=1e-9)
    outward = np.einsum("ij,ij->i", normals, mesh.nodes[faces].mean(axis=1) - [0.0, 0.0, 4.0])
    assert np.all(outward > 0)


def test_heat_distance_from_the_base_of_a_box_is_its_height(box_tets):
    _box, mesh = box_tets
    ops = fem_operators(mesh)
    base = np.flatnonzero(mesh.nodes[:, 2] < 1e-9)
    d = heat_distance(mesh, ops, base)
    err = np.abs(d - mesh.nodes[:, 2])
    assert err.max() < 0.1 * 8.0 and err.mean() < 0.02 * 8.0


def test_heat_distance_goes_round_a_wall_not_through_it():
    # a U standing on its bottom: two posts joined by a 4 mm bridge at the bottom, 4 mm deep
    u = extrude_xz(Polygon([(-10, 0), (10, 0), (10, 20), (6, 20), (6, 4), (-6, 4), (-6, 20), (-10, 20)]), 4.0)
    mesh = tetrahedralise(u, interior_nodes=4000)
    ops = fem_operators(mesh)
    src = np.flatnonzero((mesh.nodes[:, 2] > 19.99) & (mesh.nodes[:, 0] < -6.0 + 1e-6))     # top of the left post
    d = heat_distance(mesh, ops, src)
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
