"""The bundled samples and a cup slice into curved layers for the multi-axis cell, whole and in time (issue 38).

`job submit sample_part.stl --layers curved` failed after the job's 180 s: the slice took 253 s (the nozzle's
reach looked at every fan direction of 17k points four times over, most of them where the band of the ledge
round the boss was laid after the boss had risen beside it). The band follows only the part's tops; a ledge
or a cup's floor is laid by the core, solid under it; and the flared vase's lip, which the band's field left
above its top, is laid at all."""
from __future__ import annotations

import numpy as np
import pytest

from fabric.printjobs.prepare import RETRY_BUDGET_S
from fabric.robot.cell import Cell
from fabric.samples import samples
from fabric.slicing import load_profile, slice_model
from fabric.slicing.curved.axis import TiltLimits
from fabric.slicing.curved.band import followed_faces, top_patches
from fabric.slicing.curved.options import CurvedOptions
from fabric.slicing.curved.shapes import flared_vase
from fabric.slicing.curved.tetmesh import tetrahedralise

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow]   # slow: slicing the samples takes 20 s (pure logic)

PROFILE = load_profile("taz-pla-medium")


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140-multiaxis")


def _top_mm(gcode: str) -> float:
    """The highest extruding tip of a multi-axis G-code."""
    return max(float(line.split()[3][1:]) for line in gcode.splitlines() if line.startswith("G1 X"))


@pytest.mark.parametrize("name", [sample.name for sample in samples()])
def test_every_bundled_sample_slices_curved_whole_and_well_within_the_jobs_time(cell, name):
    data = next(sample for sample in samples() if sample.name == name).path.read_bytes()
    curved = slice_model(data, name, PROFILE, layers="curved", cell=cell)
    planar = slice_model(data, name, PROFILE)
    assert curved.elapsed_s < RETRY_BUDGET_S / 4, curved.elapsed_s        # 253 s before, 10 s now
    assert curved.warnings == []          # no point left where no nozzle axis clears the beads, thickness in bounds
    assert _top_mm(curved.gcode) == pytest.approx(curved.bbox_mm[1][2], abs=0.1)        # up to the part's top
    assert curved.extruded_mm3 > 0.85 * planar.extruded_mm3


def test_a_cup_lays_its_lip_and_lays_its_floor_solid_without_a_band():
    """The vase's floor is a top with the cup's wall rising round it, and what the band could follow of its lip
    has the lip rising over it: neither is followed (the band's field left the lip above its top, g < 0, and
    the slice laid 55 % of the part); the core lays both, solid within the top layers under the floor."""
    part = flared_vase()
    mesh = tetrahedralise(part, CurvedOptions().interior_nodes)
    faces, _normals = mesh.boundary_faces()
    tilts = TiltLimits(0.0, PROFILE.first_layer_height_mm, 4.0, 45.0)
    candidates = followed_faces(mesh, CurvedOptions(), tilts)
    floor = np.all(np.abs(mesh.nodes[faces, 2] - 2.0) < 1e-6, axis=1)
    assert candidates[floor].all()                      # faces up...
    assert not top_patches(mesh, faces, candidates, margin_mm=2.0)[floor].any()      # ...but is no top

    part.apply_translation([125.0, 125.0, 0.0])
    curved = slice_model(part.export(file_type="stl"), "vase.stl", PROFILE, layers="curved")
    planar = slice_model(part.export(file_type="stl"), "vase.stl", PROFILE)
    assert _top_mm(curved.gcode) == pytest.approx(part.bounds[1][2], abs=0.1)
    assert curved.extruded_mm3 > 0.85 * planar.extruded_mm3
    solid = [line for line in curved.gcode.split(";LAYER_CHANGE")
             if ";TYPE:Solid infill" in line and 1.2 < float(line.split(";Z:")[1].split()[0]) < 2.6]
    assert solid, "no solid infill under the floor's top"
