"""One volume along the pipeline: what the slicer reports, the plan and the twin's deposit agree within 0.5 %.

Crosses the seams as the services do: the slicer's G-code (bytes, its material
in its header) -> the planner (which reads the diameter back) -> the twin
(which prints the program and counts what it deposits). Property test over
parts and profiles with the built-in slicer; the external back-ends in the
``slicers`` tier.
"""
from __future__ import annotations

import math

import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fabric.demo import sample_model
from fabric.planning import plan_gcode
from fabric.robot.cell import Cell
from fabric.sim.twin import Twin
from fabric.slicing import available_backends, list_profiles, load_profile, slice_model

TOLERANCE_R = 0.005
CELL = Cell.builtin("irb140")


def _print(program) -> dict:
    """Print a program on a fresh twin as fast as possible; the finished event's figures."""
    twin = Twin(CELL)
    twin.load(program)
    twin.start()
    events = []
    while twin.state in ("printing", "paused") or twin.moving:
        events += twin.advance(1e6)
    done = [e for e in events if e.kind == "finished"]
    assert len(done) == 1, [e.kind for e in events][-5:]
    assert twin.extrusion().extruded_mm3 == pytest.approx(done[0].data["extruded_mm3"], rel=1e-12)
    return done[0].data


def check_seams(model: bytes, filename: str, profile: str, backend: str) -> tuple[float, float, float]:
    """Slice, plan and print; assert the three volumes agree and the material came from the G-code."""
    p = load_profile(profile)
    sliced = slice_model(model, filename, p, backend=backend)
    plan = plan_gcode(sliced.gcode, CELL).require_runnable()
    done = _print(plan.program)
    planned = plan.stats.extruded_volume_mm3
    assert plan.stats.material.source == "gcode" and plan.stats.material.filament_diameter_mm == p.filament_diameter_mm
    assert plan.program.meta["min_extrude_temp_c"] == p.min_extrude_temp_c
    assert planned == pytest.approx(sliced.extruded_mm3, rel=TOLERANCE_R)
    assert done["extruded_mm3"] == pytest.approx(planned, rel=TOLERANCE_R)
    # the twin's deposit is the slicer's filament in the profile's diameter
    area = math.pi * p.filament_diameter_mm ** 2 / 4
    assert done["extruded_mm3"] / area == pytest.approx(sliced.filament_mm, rel=TOLERANCE_R)
    return sliced.extruded_mm3, planned, done["extruded_mm3"]


def _part(kind: str, a_mm: float, b_mm: float, h_mm: float) -> bytes:
    if kind == "box":
        mesh = trimesh.creation.box((a_mm, b_mm, h_mm))
    else:
        mesh = trimesh.creation.cylinder(radius=a_mm / 2, height=h_mm, sections=48)
    return mesh.export(file_type="stl")


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(kind=st.sampled_from(["box", "cylinder"]), a=st.floats(8.0, 40.0), b=st.floats(8.0, 40.0),
       h=st.floats(2.0, 8.0), profile=st.sampled_from(list_profiles()))
def test_slicer_plan_and_twin_agree_on_any_part_and_profile(kind: str, a: float, b: float, h: float,
                                                            profile: str) -> None:
    check_seams(_part(kind, a, b, h), f"{kind}.stl", profile, "builtin")


@pytest.mark.parametrize("profile", list_profiles())
def test_the_sample_part_agrees_with_every_profile(profile: str) -> None:
    model = sample_model()
    check_seams(model.read_bytes(), model.name, profile, "builtin")


@pytest.mark.slicers
@pytest.mark.parametrize("backend", ["prusaslicer", "slic3r"])
@pytest.mark.parametrize("profile", list_profiles())
@pytest.mark.parametrize("part", ["sample", "box"])
def test_external_back_ends_agree_too(backend: str, profile: str, part: str) -> None:
    if available_backends().get(backend) is None:
        pytest.skip(f"{backend} is not installed")
    if part == "sample":
        model = sample_model()
        data, name = model.read_bytes(), model.name
    else:
        data, name = _part("box", 30.0, 20.0, 6.0), "box.stl"
    check_seams(data, name, profile, backend)
