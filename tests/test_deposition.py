"""Deposition: bead dimensions, growing arrays, the as-printed mesh and its export."""
from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh

from fabric.motion.program import MOVEL, Program
from fabric.sim.deposition import Deposition, bead_area_mm2
from fabric.wire.errors import ValidationError


def layered_program(heights: list[float], flow: float = 0.3, meta: dict | None = None) -> Program:
    """Two extruding moves per layer at the given nozzle heights."""
    n = 2 * len(heights)
    p = Program.empty(n, **(meta or {}))
    p.op[:] = MOVEL
    p.flow_mm3_mm[:] = flow
    for k, z in enumerate(heights):
        p.xyz_mm[2 * k] = [0.0, 0.0, z]
        p.xyz_mm[2 * k + 1] = [10.0, 0.0, z]
        p.layer[2 * k: 2 * k + 2] = k
    return p


def test_bead_dimensions_from_layer_spacing_or_meta() -> None:
    dep = Deposition(layered_program([0.3, 0.5, 0.7]))
    w, h = dep.dims(np.array([0, 1, 2]), np.full(3, 0.3))
    np.testing.assert_allclose(h, [0.3, 0.2, 0.2])
    np.testing.assert_allclose(bead_area_mm2(w, h), 0.3)       # width solved from the flow per mm
    meta = Deposition(layered_program([0.3, 0.5], meta={"bead_width_mm": 0.6, "layer_height_mm": 0.25}))
    w, h = meta.dims(np.array([0, 1]), np.full(2, 0.3))
    np.testing.assert_allclose(w, 0.6)
    np.testing.assert_allclose(h, 0.25)


def test_arrays_grow_and_mesh_volume_matches_extrusion() -> None:
    rng = np.random.default_rng(0)
    dep = Deposition(layered_program([0.3, 0.5, 0.7]))
    n = 700                                                    # past the initial capacity
    a = rng.uniform(-20, 20, (n, 3))
    b = a + rng.uniform(1, 5, (n, 3)) * rng.choice([-1, 1], (n, 3))
    b[:5, :2] = a[:5, :2]                                      # a few vertical beads
    length = np.linalg.norm(b - a, axis=1)
    flow = np.full(n, 0.3)
    dep.add(np.arange(n), rng.integers(0, 3, n), a, b, flow * length, flow)
    assert len(dep) == n and dep.row[-1] == n - 1
    mesh = dep.mesh()
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(dep.total_volume_mm3, rel=1e-9)   # octagon area = bead area
    rep = dep.volume_report(2 * dep.total_volume_mm3)
    assert rep.ratio == pytest.approx(0.5) and rep.bead_count == n
    assert rep.mesh_mm3 == pytest.approx(rep.extruded_mm3, rel=1e-9)
    # the bead hangs below the nozzle path: top at the path, bottom one height lower
    one = Deposition(layered_program([0.3]))
    one.add(np.array([0]), np.array([0]), np.array([[0.0, 0, 0.3]]), np.array([[10.0, 0, 0.3]]), [3.0], [0.3])
    lo, hi = one.mesh().bounds
    assert hi[2] == pytest.approx(0.3) and lo[2] == pytest.approx(0.0)


def test_export_stl_and_glb_round_trip() -> None:
    dep = Deposition(layered_program([0.3]))
    dep.add(np.array([0, 1]), np.array([0, 0]), np.array([[0.0, 0, 0.3], [10, 0, 0.3]]),
            np.array([[10.0, 0, 0.3], [10, 10, 0.3]]), np.array([3.0, 3.0]), np.array([0.3, 0.3]))
    stl = dep.export_mesh("stl")
    back = trimesh.load(io.BytesIO(stl), file_type="stl")
    assert len(back.faces) == 2 * 28 and back.volume == pytest.approx(6.0, rel=1e-6)
    glb = dep.export_mesh("glb")
    assert glb[:4] == b"glTF"
    scene = trimesh.load(io.BytesIO(glb), file_type="glb")
    assert sum(len(g.faces) for g in scene.geometry.values()) == 56
    with pytest.raises(ValidationError):
        dep.export_mesh("obj")
    with pytest.raises(ValidationError):
        Deposition().mesh()
