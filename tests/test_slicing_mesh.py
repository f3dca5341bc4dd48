"""Model loading, repair, placement and profiles of the slicing package (no external binaries)."""
from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest
import trimesh

from fabric.slicing import (
    Placement,
    list_profiles,
    load_mesh,
    load_profile,
    slice_model,
)
from fabric.slicing.placement import place_mesh
from fabric.slicing.samples import box, islands_part, to_stl_bytes
from fabric.wire.errors import MeshError, NotFound, PlacementError, ProfileError

BOX = box((20.0, 20.0, 10.0))
BOX_STL = to_stl_bytes(BOX)


def _ascii_stl(mesh: trimesh.Trimesh) -> bytes:
    text = mesh.export(file_type="stl_ascii")
    return text.encode() if isinstance(text, str) else text


def _three_mf(mesh: trimesh.Trimesh, unit: str = "millimeter", transform: str | None = None) -> bytes:
    """A minimal core-spec 3MF (what CAD tools write), built by hand."""
    verts = "".join(f'<vertex x="{x}" y="{y}" z="{z}"/>' for x, y, z in mesh.vertices)
    tris = "".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"/>' for a, b, c in mesh.faces)
    item = f'<item objectid="1"{f" transform={chr(34)}{transform}{chr(34)}" if transform else ""}/>'
    model = (f'<?xml version="1.0" encoding="UTF-8"?><model unit="{unit}" '
             'xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02">'
             f'<resources><object id="1" type="model"><mesh><vertices>{verts}</vertices>'
             f'<triangles>{tris}</triangles></mesh></object></resources><build>{item}</build></model>')
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("3D/3dmodel.model", model)
    return buf.getvalue()


# -- formats -------------------------------------------------------------------------------------
@pytest.mark.parametrize("name,data", [
    ("part.stl", BOX_STL),
    ("part.STL", _ascii_stl(BOX)),
    ("part.obj", BOX.export(file_type="obj").encode()),
    ("part.3mf", _three_mf(BOX)),
], ids=["binary-stl", "ascii-stl", "obj", "3mf"])     # not the bytes: a 3MF's zip holds the time it was made,
def test_formats_load_to_the_same_solid(name: str, data: bytes) -> None:
    mesh = load_mesh(data, name)
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(4000.0, rel=1e-6)
    assert np.allclose(mesh.bounds, [[-10, -10, 0], [10, 10, 10]], atol=1e-5)


def test_3mf_units_and_build_transform_are_applied() -> None:
    # 20 x 20 x 10 *cm* box, moved by (5, 0, 0) cm in the build item
    mesh = load_mesh(_three_mf(BOX, unit="centimeter", transform="1 0 0 0 1 0 0 0 1 5 0 0"), "p.3mf")
    assert mesh.volume == pytest.approx(4000.0 * 1000.0, rel=1e-6)
    assert mesh.bounds[0, 0] == pytest.approx(-50.0)


# -- broken inputs -------------------------------------------------------------------------------
def test_empty_file_is_a_mesh_error_naming_the_file() -> None:
    with pytest.raises(MeshError, match=r"bracket\.stl: the file is empty") as err:
        load_mesh(b"", "bracket.stl")
    assert err.value.details["reason"] == "empty"


def test_truncated_binary_stl_says_how_much_is_missing() -> None:
    with pytest.raises(MeshError, match="truncated binary STL") as err:
        load_mesh(BOX_STL[:-20], "cut.stl")
    assert err.value.details["expected_bytes"] - err.value.details["actual_bytes"] == 20


def test_truncated_ascii_stl() -> None:
    text = _ascii_stl(BOX)
    with pytest.raises(MeshError, match="truncated ascii STL"):
        load_mesh(text[: len(text) // 2], "cut.stl")


def test_non_manifold_mesh_is_refused() -> None:
    v = np.vstack([BOX.vertices, [[0.0, 0.0, 30.0]]])
    a, b = BOX.edges_unique[0]
    f = np.vstack([BOX.faces, [[a, b, len(v) - 1]]])      # a fin on an existing edge
    with pytest.raises(MeshError, match="non-manifold") as err:
        load_mesh(to_stl_bytes(trimesh.Trimesh(v, f, process=False)), "fin.stl")
    assert err.value.details["edges"] == 1


def test_large_hole_is_refused_small_hole_is_closed() -> None:
    with pytest.raises(MeshError, match="too large to close safely") as err:
        load_mesh(to_stl_bytes(trimesh.Trimesh(BOX.vertices, BOX.faces[2:], process=False)), "open.stl")
    assert err.value.details["hole_span_mm"] == pytest.approx(20.0)
    sphere = trimesh.creation.icosphere(4, 10.0)
    mesh = load_mesh(to_stl_bytes(trimesh.Trimesh(sphere.vertices, sphere.faces[1:], process=False)), "s.stl")
    assert mesh.is_watertight and mesh.volume == pytest.approx(sphere.volume, rel=1e-3)
    assert any("closed 1 small holes" in n for n in mesh.metadata["repairs"])


def test_inside_out_duplicate_and_degenerate_faces_are_repaired() -> None:
    inv = BOX.copy()
    inv.invert()
    faces = np.vstack([inv.faces, inv.faces[:2], [[0, 0, 1]]])
    mesh = load_mesh(to_stl_bytes(trimesh.Trimesh(inv.vertices, faces, process=False)), "bad.stl")
    assert mesh.volume == pytest.approx(4000.0) and len(mesh.faces) == 12
    assert len(mesh.metadata["repairs"]) == 2


@pytest.mark.parametrize("data,name,match", [
    (b"not a mesh at all, just text" * 5, "x.stl", "not an STL"),
    (BOX_STL, "x.step", "unsupported model format"),
    (b"PK\x03\x04garbage", "x.3mf", "3MF"),
])
def test_unreadable_inputs(data: bytes, name: str, match: str) -> None:
    with pytest.raises(MeshError, match=match):
        load_mesh(data, name)


def test_flat_model_is_refused() -> None:
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 1]], process=False)
    with pytest.raises(MeshError, match="flat"):
        load_mesh(to_stl_bytes(flat), "flat.stl")


# -- placement -----------------------------------------------------------------------------------
def test_placement_centres_on_the_plate_and_rotates() -> None:
    placed = place_mesh(BOX, None)
    assert np.allclose(placed.bounds, [[115, 115, 0], [135, 135, 10]])
    long = box((30.0, 10.0, 5.0))
    turned = place_mesh(long, Placement(center_xy_mm=(50.0, 60.0), rotate_z_deg=90.0))
    assert np.allclose(turned.bounds, [[45, 45, 0], [55, 75, 5]], atol=1e-9)


def test_part_larger_than_the_plate_names_axis_and_excess() -> None:
    with pytest.raises(PlacementError, match=r"part is 300\.00 mm in X, 50\.00 mm more") as err:
        place_mesh(box((300.0, 20.0, 10.0)), None)
    assert err.value.details["axis"] == "X" and err.value.details["excess_mm"] == pytest.approx(50.0)
    with pytest.raises(PlacementError, match="build height") as err:
        place_mesh(box((20.0, 20.0, 260.0)), None, build_height_mm=250.0)
    assert err.value.details["axis"] == "Z"


def test_part_off_the_plate_edge() -> None:
    with pytest.raises(PlacementError, match=r"sticks out of the plate by 5.00 mm at Y max") as err:
        place_mesh(BOX, Placement(center_xy_mm=(125.0, 245.0)))
    assert err.value.details == {"axis": "Y", "side": "max", "excess_mm": pytest.approx(5.0)}


def test_slice_model_reports_broken_input_before_slicing() -> None:
    prof = load_profile("taz-pla-medium")
    with pytest.raises(MeshError):
        slice_model(b"", "a.stl", prof)
    with pytest.raises(PlacementError):
        slice_model(to_stl_bytes(box((260.0, 10.0, 10.0))), "a.stl", prof)
    with pytest.raises(NotFound, match="unknown slicer back-end 'cura'"):
        slice_model(BOX_STL, "a.stl", prof, backend="cura")


# -- profiles ------------------------------------------------------------------------------------
def test_shipped_profiles_load() -> None:
    assert {"taz-pla-medium", "robot-1.2mm"} <= set(list_profiles())
    taz = load_profile("taz-pla-medium")
    assert (taz.nozzle_diameter_mm, taz.filament_diameter_mm) == (0.35, 2.85)
    robot = load_profile("robot-1.2mm")
    assert robot.nozzle_diameter_mm == 1.2 and robot.layer_height_mm == 0.6


def test_overrides_are_parsed_to_the_field_type() -> None:
    p = load_profile("taz-pla-medium", {"perimeters": "3", "infill_density_r": "35%",
                                         "layer_height_mm": "0.2", "infill_pattern": "grid"})
    assert p.perimeters == 3 and isinstance(p.perimeters, int)
    assert p.infill_density_r == pytest.approx(0.35) and p.layer_height_mm == 0.2
    assert p.infill_pattern == "grid"


@pytest.mark.parametrize("overrides,key", [
    ({"nozzle_size": "0.4"}, "nozzle_size"),
    ({"perimeters": "two"}, "perimeters"),
    ({"infill_density_r": "1.5"}, "infill_density_r"),
    ({"seam": "random"}, "seam"),
    ({"layer_height_mm": "0.5"}, "layer_height_mm"),          # thicker than the 0.35 nozzle
])
def test_bad_profile_values_name_the_key(overrides: dict[str, str], key: str) -> None:
    with pytest.raises(ProfileError, match=key) as err:
        load_profile("taz-pla-medium", overrides)
    assert err.value.details["key"] == key


def test_profile_from_a_path_and_unknown_profile(tmp_path) -> None:
    path = tmp_path / "mine.toml"
    path.write_text('layer_height_mm = 0.2\ninfill_pattern = "grid"\n')
    assert load_profile(str(path)).layer_height_mm == 0.2
    path.write_text("layer_hieght_mm = 0.2\n")
    with pytest.raises(ProfileError, match="unknown profile key 'layer_hieght_mm'"):
        load_profile(str(path))
    with pytest.raises(NotFound, match="unknown profile"):
        load_profile("no-such-profile")


def test_islands_part_is_a_valid_test_shape() -> None:
    mesh = load_mesh(to_stl_bytes(islands_part()), "islands.stl")
    assert len(mesh.split(only_watertight=True)) == 3
