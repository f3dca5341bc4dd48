"""PrusaSlicer and Slic3r back-ends: profile mapping, shared G-code conventions, failures."""
from __future__ import annotations

import re
import shutil

import numpy as np
import pytest

from fabric.slicing import (
    Placement,
    available_backends,
    external,
    load_profile,
    slice_model,
)
from fabric.slicing import backends as backends_mod
from fabric.slicing.gcode_stats import gcode_stats
from fabric.slicing.samples import islands_part, to_stl_bytes
from fabric.wire.errors import NotFound, SlicerError

TAZ = load_profile("taz-pla-medium")
ISLANDS = to_stl_bytes(islands_part())
INSTALLED = {name: shutil.which(spec["exe"]) is not None for name, spec in external.EXTERNAL.items()}


# -- pure mapping (no binaries) -------------------------------------------------------------------
def test_prusaslicer_ini_matches_the_builtin_conventions() -> None:
    ini = external.prusaslicer_ini(TAZ.replace(infill_density_r=0.3), (250.0, 200.0), 180.0)
    assert ini["bed_shape"] == "0x0,250x0,250x200,0x200" and ini["max_print_height"] == "180"
    assert ini["use_relative_e_distances"] == "1" and ini["perimeter_generator"] == "classic"
    assert ini["fill_density"] == "30%" and ini["infill_overlap"] == "25%"
    assert ini["thin_walls"] == ini["infill_anchor_max"] == "0"
    assert ini["gap_fill_enabled"] == ini["avoid_crossing_perimeters"] == "1"      # as the built-in slicer does
    assert ini["only_retract_when_crossing_perimeters"] == "1" and ini["retract_layer_change"] == "0"
    assert {ini[k] for k in ini if k.endswith("extrusion_width")} == {"0.42"}
    assert "G28" not in ini["start_gcode"] and "\\nM140 S60\\nM104 S205" in ini["start_gcode"]
    assert ini["start_gcode"].startswith("; filament_diameter = 2.85\\n; filament_type = PLA\\n")
    assert "M83" in ini["start_gcode"] and "G28" not in ini["end_gcode"]


def test_slic3r_ini_adds_layer_markers_and_move_comments() -> None:
    ini = external.slic3r_ini(TAZ, (250.0, 250.0), 250.0)
    assert ini["before_layer_gcode"] == ";LAYER_CHANGE\\n;Z:[layer_z]\\n"
    assert ini["gcode_comments"] == "1" and ini["fill_gaps"] == "1"


def test_slic3r_comments_become_type_markers() -> None:
    raw = ("G1 Z0.300 F7800.000 ; move to next layer (0)\n"
           "G1 X1 Y1 E0.1 ; perimeter\nG1 X2 Y1 E0.1 ; perimeter\n"
           "G1 X3 Y3 F7800.000 ; move to first infill point\nG1 X4 Y3 E0.2 ; infill\n")
    out = external._slic3r_types(raw)
    assert out.splitlines()[1:4] == [";TYPE:Perimeter", "G1 X1 Y1 E0.1", "G1 X2 Y1 E0.1"]
    assert ";TYPE:Infill\nG1 X4 Y3 E0.2" in out


def test_gcode_stats_reads_relative_and_absolute_e_alike() -> None:
    relative = ("M83\n;LAYER_CHANGE\n;Z:0.3\nG1 E-1 F1500\nG1 X1 Y0 F9000\nG1 E1 F1500\n;TYPE:Perimeter\n"
                "G1 X2 Y0 E0.5\nG1 X2 Y1 E0.25\n;LAYER_CHANGE\n;Z:0.55\n;TYPE:Solid infill\nG1 X3 Y1 E0.25\n")
    absolute = ("M82\nG92 E0\n;LAYER_CHANGE\n;Z:0.3\nG1 E-1 F1500\nG1 X1 Y0 F9000\nG1 E0 F1500\n"
                ";TYPE:Perimeter\nG1 X2 Y0 E0.5\nG1 X2 Y1 E0.75\n;LAYER_CHANGE\n;Z:0.55\n"
                ";TYPE:Solid infill\nG92 E0\nG1 X3 Y1 E0.25\n")
    area = np.pi * 1.425 ** 2
    for text in (relative, absolute):
        st = gcode_stats(text, 2.85)
        assert st.layers == 2 and st.layer_z_mm == [0.3, 0.55]
        assert st.extruded_filament_mm == pytest.approx(1.0) and st.net_filament_mm == pytest.approx(1.0)
        assert st.volume_by_type_mm3 == pytest.approx({"Perimeter": 0.75 * area, "Solid infill": 0.25 * area})


def test_gcode_stats_counts_retractions_and_travel_alike_for_relative_and_absolute_e() -> None:
    relative = ("M83\nG1 X0 Y0 F9000\nG1 X3 Y0 E0.5\nG1 E-1 F1500\nG1 X3 Y4 F9000\nG1 X0 Y4\nG1 E1 F1500\n"
                "G1 X0 Y5 E0.1\nG1 Z0.6 F9000\nG1 X0 Y7 F9000\nG1 X1 Y7 E0.1\n")
    absolute = ("M82\nG92 E0\nG1 X0 Y0 F9000\nG1 X3 Y0 E0.5\nG1 E-0.5 F1500\nG1 X3 Y4 F9000\nG1 X0 Y4\n"
                "G1 E0.5 F1500\nG1 X0 Y5 E0.6\nG1 Z0.6 F9000\nG1 X0 Y7 F9000\nG1 X1 Y7 E0.7\n")
    for text in (relative, absolute):
        st = gcode_stats(text, 2.85)
        assert st.retractions == 1                       # the E-only pull-back; the push back is not one
        assert st.travel_mm == pytest.approx(4.0 + 3.0 + 2.0)     # two travel legs, one unretracted hop


def test_unknown_or_missing_backend_is_not_found(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(NotFound):
        external.run_external("cura", islands_part(), TAZ, (250.0, 250.0), 250.0)
    monkeypatch.setattr(backends_mod, "external_version", lambda name: None)
    with pytest.raises(NotFound, match="not installed"):
        slice_model(ISLANDS, "i.stl", TAZ, backend="slic3r")


# -- the real binaries ----------------------------------------------------------------------------
@pytest.mark.slicers
def test_available_backends_report_versions() -> None:
    found = available_backends()
    assert found["builtin"]
    if INSTALLED["prusaslicer"]:
        assert re.fullmatch(r"2\.\d+\.\d+", found["prusaslicer"] or "")
    if INSTALLED["slic3r"]:
        assert re.fullmatch(r"1\.\d+\.\d+", found["slic3r"] or "")


@pytest.mark.slicers
@pytest.mark.parametrize("backend", ["prusaslicer", "slic3r"])
def test_external_gcode_follows_the_shared_conventions(backend: str) -> None:
    if not INSTALLED[backend]:
        pytest.skip(f"{backend} not installed")
    place = Placement(center_xy_mm=(60.0, 80.0), rotate_z_deg=30.0)
    res = slice_model(ISLANDS, "islands.stl", TAZ, backend=backend, placement=place)
    ours = slice_model(ISLANDS, "islands.stl", TAZ, placement=place)
    g = res.gcode
    assert "G28" not in g
    head = g.split(";LAYER_CHANGE")[0]
    assert all(code in head for code in ("M140 S60", "M104 S205", "M190 S60", "M109 S205", "M83"))
    assert "M82" not in g
    assert len(re.findall(r"^;LAYER_CHANGE$", g, re.M)) == res.layers
    assert abs(res.layers - ours.layers) <= (0 if backend == "prusaslicer" else 1)
    assert ";TYPE:Perimeter" in g
    # extruding moves lie on the placed part (plus the skirt around it)
    xy = np.array([(float(x), float(y)) for x, y in re.findall(r"^G1 X(-?[\d.]+) Y(-?[\d.]+) E[\d.]", g, re.M)])
    lo, hi = np.array(res.bbox_mm)[:, :2]
    margin = TAZ.skirt_distance_mm + 1.0
    assert (xy >= lo - margin).all() and (xy <= hi + margin).all()
    assert np.allclose(xy.mean(axis=0), ours_mean := _extruded_mean(ours.gcode), atol=3.0), ours_mean
    stats = gcode_stats(g, TAZ.filament_diameter_mm)
    assert stats.extruded_mm3 == pytest.approx(res.extruded_mm3)
    assert res.extruded_mm3 == pytest.approx(ours.extruded_mm3, rel=0.15)


def _extruded_mean(gcode: str) -> np.ndarray:
    return np.array([(float(x), float(y)) for x, y in
                     re.findall(r"^G1 X(-?[\d.]+) Y(-?[\d.]+) E[\d.]", gcode, re.M)]).mean(axis=0)


@pytest.mark.slicers
def test_a_failing_slicer_reports_exit_code_and_stderr(monkeypatch: pytest.MonkeyPatch) -> None:
    if not INSTALLED["prusaslicer"]:
        pytest.skip("prusa-slicer not installed")
    spec = dict(external.EXTERNAL["prusaslicer"])
    good = spec["argv"]
    spec["argv"] = lambda ini, out, model: [*good(ini, out, model)[:-1], "--no-such-option", model]
    monkeypatch.setitem(external.EXTERNAL, "prusaslicer", spec)
    with pytest.raises(SlicerError, match="prusaslicer failed with exit code") as err:
        slice_model(ISLANDS, "i.stl", TAZ, backend="prusaslicer")
    assert err.value.details["exit_code"] != 0
    assert any("no-such-option" in line for line in err.value.details["stderr_tail"])
