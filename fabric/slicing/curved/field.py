"""The layer fields of a part: geodesic distance from the base, a top band that follows the top surface,
and the nozzle axis field derived from them.

Two scalar fields on the volume mesh define the layers:

* the *core* field ``d_base``: the geodesic distance from the plate contact,
  measured inside the part (:mod:`.heat`). Its level sets grow out of the base
  like wave fronts, so they climb along an outward-leaning wall (the wall's
  normal is perpendicular to the front's direction: no overhang) and up both
  legs of an arch. Layers are its level sets, ``nominal`` apart along the gradient.
* the *band* field ``d_top``: the distance from the top surface (faces whose
  normal is within ``top_slope_deg`` of +z). The last ``top_band_layers``
  layers are its level sets ``d_top = const`` below the top, so the part's top
  is itself the last layer's upper surface and has no staircase; the core
  stops where the band begins. The band keeps ``side_margin_mm`` away from
  the part's other walls (those not top, not on the plate): there the core's
  layers climb the wall to the top, so the band never reaches out over a
  wall that leans outwards (which would be an overhang).

The build direction at a node is the unit gradient of the field it belongs to
(``+grad d_base`` in the core, ``-grad d_top`` in the band); a layer of field
step ``s`` is ``s / |grad|`` thick there, ``|grad|`` the mean of the adjacent
elements' gradient lengths (the length of their mean gradient drops where two
fronts meet: 0.17 on an arch's crown, which read the layers there as almost
six times their step and thinned the whole layer for it). The nozzle axis is
that direction smoothed over the mesh (Laplacian passes over its edges,
which averages it with its neighbours in every direction, across layers too)
and then limited to the tilt the cell reaches (rotated towards +z in the
vertical plane that holds it).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from fabric.slicing.curved.heat import (
    FemOperators,
    fem_operators,
    geodesic_distance,
    node_gradient_norms,
    node_gradients,
)
from fabric.slicing.curved.options import CurvedOptions
from fabric.slicing.curved.tetmesh import TetMesh
from fabric.wire.errors import MeshError

__all__ = ["LayerField", "build_field", "limit_tilt", "base_nodes", "surface_kinds"]

BASE_TOL_MM = 0.02       # a vertex this close to the lowest point touches the plate
MIN_SMOOTHING_PASSES = 2


@dataclass(frozen=True)
class LayerField:
    """Everything the layer extraction reads from the volume mesh (arrays per node)."""

    mesh: TetMesh
    ops: FemOperators
    d_base_mm: np.ndarray        # geodesic distance from the plate contact
    d_top_mm: np.ndarray         # geodesic distance from the top surface (inf without a top)
    band_mm: float               # depth of the top band (0: no band)
    core_dir: np.ndarray         # (n, 3) unit gradient of d_base
    core_grad_r: np.ndarray      # (n,) |grad d_base|, mean over the adjacent elements (1 for an exact distance)
    band_dir: np.ndarray         # (n, 3) unit -grad d_top
    band_grad_r: np.ndarray      # (n,) |grad d_top|, likewise
    axis: np.ndarray             # (n, 3) nozzle axis: smoothed, tilt-limited build direction
    in_band: np.ndarray          # (n,) bool
    band_clip_mm: np.ndarray     # (n,) max(d_top - band, margin - d_side): < 0 in the band, >= 0 in the core

    @property
    def build_dir(self) -> np.ndarray:
        """(n, 3) the local build direction: the gradient of the field each node belongs to."""
        return np.where(self.in_band[:, None], self.band_dir, self.core_dir)


def base_nodes(nodes: np.ndarray) -> np.ndarray:
    """Indices of the nodes that rest on the plate (only surface nodes can be that low)."""
    z = nodes[:, 2]
    return np.flatnonzero(z <= z.min() + BASE_TOL_MM)


def surface_kinds(mesh: TetMesh, top_slope_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(top, side) masks over the boundary faces: facing up within ``top_slope_deg`` and off the plate, or
    neither top nor on the plate. Every surface node counts, the ones TetGen added too."""
    faces, normals = mesh.boundary_faces()
    zmin = float(mesh.nodes[:, 2].min())
    on_plate = np.all(mesh.nodes[faces][:, :, 2] <= zmin + BASE_TOL_MM, axis=1)
    up = (normals[:, 2] >= math.cos(math.radians(top_slope_deg))) & ~on_plate
    return up, ~up & ~on_plate


def _side_distance(mesh: TetMesh, side_faces: np.ndarray, reach_mm: float) -> np.ndarray:
    """Straight distance (mm) from every node to the nearest node of a side wall (inf without walls), exact
    up to ``reach_mm`` plus the longest mesh edge (farther nodes get that bound): enough for every edge that
    the band's clip value crosses zero on."""
    if len(side_faces) == 0:
        return np.full(len(mesh.nodes), np.inf)
    e = mesh.edges
    bound = reach_mm + float(np.linalg.norm(mesh.nodes[e[:, 0]] - mesh.nodes[e[:, 1]], axis=1).max())
    dist, _ = cKDTree(mesh.nodes[np.unique(side_faces.ravel())]).query(mesh.nodes, distance_upper_bound=bound)
    return np.minimum(np.asarray(dist), bound)


def limit_tilt(axes: np.ndarray, max_tilt_deg: float) -> np.ndarray:
    """Unit axes rotated towards +z (in their vertical plane) so none is tilted more than ``max_tilt_deg``."""
    a = axes / np.maximum(np.linalg.norm(axes, axis=1, keepdims=True), 1e-12)
    cos_max = math.cos(math.radians(max_tilt_deg))
    over = a[:, 2] < cos_max
    if np.any(over):
        horiz = a[over].copy()
        horiz[:, 2] = 0.0
        hn = np.linalg.norm(horiz, axis=1, keepdims=True)
        horiz = np.where(hn > 1e-9, horiz / np.maximum(hn, 1e-12), np.array([1.0, 0.0, 0.0]))
        s = math.sin(math.radians(max_tilt_deg))
        a[over] = horiz * s + np.array([0.0, 0.0, cos_max])
    return a


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    norm = np.linalg.norm(v, axis=1)
    return v / np.maximum(norm, 1e-12)[:, None], norm


def _nozzle_axes(build: np.ndarray, edges: np.ndarray, options: CurvedOptions) -> np.ndarray:
    """Tilt-limited nozzle axes: the build direction smoothed over the mesh edges (Laplacian passes,
    renormalised), as few passes as bring every edge's two axes within ``max_neighbour_deg`` (at least
    ``MIN_SMOOTHING_PASSES``, at most ``axis_smoothing_passes``), so the nozzle stays as close to the
    layer normal as the neighbour limit allows."""
    n = len(build)
    adj = sp.csr_matrix((np.ones(2 * len(edges)), (np.r_[edges[:, 0], edges[:, 1]], np.r_[edges[:, 1], edges[:, 0]])),
                        shape=(n, n))
    deg = np.asarray(adj.sum(axis=1))
    cos_limit = math.cos(math.radians(options.max_neighbour_deg))
    out = build
    axes = limit_tilt(out, options.max_tilt_deg)
    for k in range(options.axis_smoothing_passes):
        out = 0.5 * out + 0.5 * (adj @ out) / np.maximum(deg, 1.0)
        out, _norm = _unit(out)
        axes = limit_tilt(out, options.max_tilt_deg)
        if k + 1 >= MIN_SMOOTHING_PASSES and np.einsum("ij,ij->i", axes[edges[:, 0]], axes[edges[:, 1]]).min() \
                >= cos_limit:
            break
    return axes


def build_field(mesh: TetMesh, options: CurvedOptions, nominal_mm: float, side_margin_mm: float) -> LayerField:
    """Solve the core and band fields on ``mesh`` (a tetrahedralised part) and derive the nozzle axes."""
    ops = fem_operators(mesh)
    base = base_nodes(mesh.nodes)
    if len(base) == 0:
        raise MeshError("curved slicing: the part does not touch the plate", reason="no_base")
    d_base = geodesic_distance(mesh, ops, base, options.heat_time_r)
    core_dir, _norm = _unit(node_gradients(ops, mesh.tets, d_base))
    core_grad = node_gradient_norms(ops, mesh.tets, d_base)
    n = len(mesh.nodes)
    faces, _normals = mesh.boundary_faces()
    up, side = surface_kinds(mesh, options.top_slope_deg)
    band_mm = options.top_band_layers * nominal_mm if np.any(up) else 0.0
    if band_mm > 0.0:
        d_top = geodesic_distance(mesh, ops, np.unique(faces[up].ravel()), options.heat_time_r)
        band_dir, _norm = _unit(-node_gradients(ops, mesh.tets, d_top))
        band_grad = node_gradient_norms(ops, mesh.tets, d_top)
        margin = max(side_margin_mm, band_mm)
        clip = np.maximum(d_top - band_mm, margin - _side_distance(mesh, faces[side], margin))
    else:
        d_top = np.full(n, np.inf)
        band_dir, band_grad = core_dir, core_grad
        clip = np.full(n, np.inf)
    in_band = clip < 0.0
    build = np.where(in_band[:, None], band_dir, core_dir)
    axis = _nozzle_axes(build, mesh.edges, options)
    return LayerField(mesh=mesh, ops=ops, d_base_mm=d_base, d_top_mm=d_top, band_mm=band_mm, core_dir=core_dir,
                      core_grad_r=core_grad, band_dir=band_dir, band_grad_r=band_grad, axis=axis, in_band=in_band,
                      band_clip_mm=clip)
