"""The curved slicer's rules for where two fronts of layers meet: the crease rounded, the nozzle turned clear."""
from __future__ import annotations

import itertools

import numpy as np
import pytest
import trimesh

from fabric.slicing.curved.axis import TiltLimits, unit_rows
from fabric.slicing.curved.crease import crease_nodes, round_creases
from fabric.slicing.curved.heat import fem_operators, node_gradients
from fabric.slicing.curved.options import CurvedOptions
from fabric.slicing.curved.paths import CurvedPath
from fabric.slicing.curved.reach import NozzleReach, nozzle_pieces
from fabric.slicing.curved.tetmesh import tetrahedralise

pytestmark = pytest.mark.timeout(120)


def _tilt_deg(v: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(unit_rows(v)[:, 2], -1.0, 1.0)))


def test_a_v_shaped_crease_is_rounded_near_it_and_left_alone_away_from_it():
    """Two fronts leaning 53 degrees towards each other meet at x = 0 (an arch's crown in small): at the crease
    the rounded field's layers lean far less (measured: at most 31 degrees within 0.3 mm, 41 before); a mesh
    ring past 3 mm they are exactly what they were."""
    box = trimesh.creation.box((20.0, 10.0, 8.0))
    box.apply_translation([0.0, 0.0, 4.0])
    mesh = tetrahedralise(box, interior_nodes=3000)
    ops = fem_operators(mesh)
    x, z = mesh.nodes[:, 0], mesh.nodes[:, 2]
    d = 0.6 * z - 0.8 * np.abs(x)
    crease, _mean = crease_nodes(mesh, ops, d)
    assert len(crease) and np.abs(x[crease]).max() < 1.5                    # found where the fronts meet
    rounded = round_creases(mesh, ops, d, weight_r=0.5, width_mm=3.0)
    before = _tilt_deg(node_gradients(ops, mesh.tets, d))
    after = _tilt_deg(node_gradients(ops, mesh.tets, rounded))
    at = np.abs(x) < 1.2
    away = np.abs(x) > 3.0 + 1.5
    assert before[at].mean() - after[at].mean() > 4.0 and after[np.abs(x) < 0.3].max() < 35.0
    np.testing.assert_array_equal(rounded[away], d[away])
    assert round_creases(mesh, ops, d, weight_r=0.0, width_mm=3.0) is d        # off: untouched
    flat = 0.6 * z                                                              # no crease: untouched
    np.testing.assert_array_equal(round_creases(mesh, ops, flat, 0.5, 3.0), flat)


def test_the_nozzle_is_looked_along_as_the_cells_collision_model_covers_it():
    opts = CurvedOptions()
    pieces = nozzle_pieces(opts)
    assert pieces[0][0] == opts.nozzle_tip_length_mm                            # the tip itself may touch
    assert pieces[-1][1] == pytest.approx(opts.nozzle_reach_mm)
    assert all(a[1] == pytest.approx(b[0]) for a, b in itertools.pairwise(pieces))
    taper = [p for p in pieces if p[1] <= opts.nozzle_tip_length_mm + opts.nozzle_taper_mm + 1e-9]
    assert sorted({round(r, 6) for _a, _b, r in taper}) == pytest.approx([0.35 + 0.65 / 3, 0.35 + 1.3 / 3, 1.0])
    assert NozzleReach(CurvedOptions(nozzle_radius_mm=0.0)).pieces == []     # off


def _path(x_mm: float, axis: list[float], n: int = 41) -> CurvedPath:
    y = np.linspace(-4.0, 4.0, n)
    pts = np.column_stack([np.full(n, x_mm), y, np.zeros(n)])
    ax = np.tile(unit_rows(np.array([axis], dtype=float)), (n, 1))
    return CurvedPath(layer=0, role="perimeter", points_mm=pts, axes=ax.copy(), normals=ax.copy(),
                      heights_mm=np.full(n, 0.3), width_mm=0.45, closed=False)


def _wall(x_mm: float) -> CurvedPath:
    """Bead centres laid before: a wall standing at ``x_mm``, 10 mm high."""
    y, z = np.meshgrid(np.arange(-8.0, 8.01, 0.2), np.arange(0.0, 10.0, 0.3))
    pts = np.column_stack([np.full(y.size, x_mm), y.ravel(), z.ravel() + 0.15])
    up = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    return CurvedPath(layer=0, role="perimeter", points_mm=pts, axes=up, normals=up, heights_mm=np.full(len(pts), 0.3),
                      width_mm=0.45, closed=False)


def test_a_nozzle_leaning_into_a_wall_is_turned_clear_and_one_leaning_away_is_not():
    reach = NozzleReach(CurvedOptions())
    reach._laid.append(_wall(1.5).points_mm - [0.0, 0.0, 0.15])           # laid before (bead centres)
    into = _path(0.0, [1.0, 0.0, 1.0])           # 45 degrees towards the wall 1.5 mm away: the cone meets it
    away = _path(-0.5, [-1.0, 0.0, 1.0])
    far = _path(-30.0, [1.0, 0.0, 1.0])
    lean_before = [p.axes.copy() for p in (away, far)]
    reach.hold([into, away, far], TiltLimits(plate_z_mm=0.0, first_layer_mm=0.3, tip_radius_mm=0.0,
                                             max_tilt_deg=45.0))
    tree_check = NozzleReach(CurvedOptions())
    tree_check._laid = list(reach._laid[:1])
    from scipy.spatial import cKDTree
    tree = cKDTree(reach._laid[0])
    assert not tree_check._blocked(into.points_mm, into.axes, [tree], 0.5 * 0.45 + 0.1).any()
    assert _tilt_deg(into.axes).max() < 30.0 and (into.axes[:, 0] >= -1e-9).all()   # turned up, not past
    np.testing.assert_array_equal(away.axes, lean_before[0])
    np.testing.assert_array_equal(far.axes, lean_before[1])
    assert reach.turned == len(into.axes) and reach.blocked == 0
