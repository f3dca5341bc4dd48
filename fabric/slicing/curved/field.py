"""The layer fields of a part: geodesic distance from the base, a top band that follows the top surface,
and the nozzle axis field derived from them.

Two scalar fields on the volume mesh define the layers:

* the *core* field ``d_base``: the geodesic distance from the plate contact,
  measured inside the part (:mod:`.heat`). Its level sets grow out of the base
  like wave fronts, so they climb along an outward-leaning wall (the wall's
  normal is perpendicular to the front's direction: no overhang) and up both
  legs of an arch, where they meet in a crease over the crown, which is rounded
  (:mod:`.crease`), and lean no further than the nozzle can follow them
  (:mod:`.lean`: round a hook's curl they would lean past horizontal).
  Layers are its level sets, ``nominal`` apart along the gradient.
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
and then limited to the tilt the cell reaches there, the way it leans
(:class:`.axis.TiltLimits`: rotated towards +z in the vertical plane that
holds it). Core layers end solid under the tops the band does not follow
(:mod:`.tops`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from fabric.slicing.curved.axis import TiltLimits, limit_deviation, limit_tilt, unit_rows
from fabric.slicing.curved.band import build_band
from fabric.slicing.curved.crease import round_creases
from fabric.slicing.curved.heat import (
    FemOperators,
    fem_operators,
    geodesic_distance,
    node_gradient_norms,
    node_gradients,
)
from fabric.slicing.curved.lean import limit_lean
from fabric.slicing.curved.options import CurvedOptions
from fabric.slicing.curved.tetmesh import TetMesh
from fabric.slicing.curved.tops import under_tops_mm
from fabric.wire.errors import MeshError

__all__ = ["LayerField", "build_field", "limit_tilt", "base_nodes", "plate_blend"]

BASE_TOL_MM = 0.02       # a vertex this close to the lowest point touches the plate
MIN_SMOOTHING_PASSES = 2
CREASE_RINGS = 2         # rings of nodes round a crease of the layers where the axis may leave their normal


@dataclass(frozen=True)
class LayerField:
    """Everything the layer extraction reads from the volume mesh (arrays per node)."""

    mesh: TetMesh
    ops: FemOperators
    d_base_mm: np.ndarray        # geodesic distance from the plate contact
    d_top_mm: np.ndarray         # the band field: 0 on the followed top faces (inf without a band, :mod:`.band`)
    band_mm: float               # depth of the top band (0: no band)
    core_dir: np.ndarray         # (n, 3) unit gradient of d_base
    core_grad_r: np.ndarray      # (n,) |grad d_base|, mean over the adjacent elements (1 for an exact distance)
    band_dir: np.ndarray         # (n, 3) unit -grad d_top
    band_grad_r: np.ndarray      # (n,) |grad d_top|, likewise
    axis: np.ndarray             # (n, 3) nozzle axis: smoothed, tilt-limited build direction
    in_band: np.ndarray          # (n,) bool
    band_clip_mm: np.ndarray     # (n,) d_top - band: < 0 in the band, >= 0 in the core
    followed: np.ndarray         # (f,) bool over mesh.boundary_faces(): the top faces the band follows
    under_top_mm: np.ndarray     # (n,) distance from the nearest top the band does not follow (:mod:`.tops`)

    @property
    def build_dir(self) -> np.ndarray:
        """(n, 3) the local build direction: the gradient of the field each node belongs to."""
        return np.where(self.in_band[:, None], self.band_dir, self.core_dir)


def base_nodes(nodes: np.ndarray) -> np.ndarray:
    """Indices of the nodes that rest on the plate (only surface nodes can be that low)."""
    z = nodes[:, 2]
    return np.flatnonzero(z <= z.min() + BASE_TOL_MM)


def _crease_half_angles_deg(build: np.ndarray, edges: np.ndarray, adj: sp.csr_matrix) -> np.ndarray:
    """(n,) half the largest turn of the build direction across each node's edges, spread :data:`CREASE_RINGS`
    rings of edges out. Where layers meet at a crease (an arch's crown, where the layers that climbed both
    legs join) the layer normal itself turns by up to twice the tilt limit between two nodes; no axis close to
    both sides' normals exists there, so the axis may leave the normal by half the turn, over a few rings of
    nodes, and turn smoothly from one side to the other."""
    cos = np.clip(np.einsum("ij,ij->i", build[edges[:, 0]], build[edges[:, 1]]), -1.0, 1.0)
    half = 0.5 * np.degrees(np.arccos(cos))
    out = np.zeros(len(build))
    np.maximum.at(out, edges[:, 0], half)
    np.maximum.at(out, edges[:, 1], half)
    for _ring in range(CREASE_RINGS):
        out = np.maximum(out, np.asarray(adj.multiply(out[None, :]).max(axis=1).todense()).ravel())
    return out


def _nozzle_axes(build: np.ndarray, edges: np.ndarray, nodes: np.ndarray, tilts: TiltLimits, options: CurvedOptions,
                 ) -> np.ndarray:
    """Tilt-limited nozzle axes: the build direction smoothed over the mesh edges (Laplacian passes,
    renormalised, each kept within ``max_axis_deviation_deg`` of the node's build direction), as few passes
    as bring every edge's two axes within ``max_neighbour_deg`` (at least ``MIN_SMOOTHING_PASSES``, at most
    ``axis_smoothing_passes``), then limited to the tilt allowed at each node (``tilts``)."""
    n = len(build)
    adj = sp.csr_matrix((np.ones(2 * len(edges)), (np.r_[edges[:, 0], edges[:, 1]], np.r_[edges[:, 1], edges[:, 0]])),
                        shape=(n, n))
    deg = np.asarray(adj.sum(axis=1))
    cos_limit = math.cos(math.radians(options.max_neighbour_deg))
    out = build
    axes = tilts.hold(nodes, out)
    allowed = np.maximum(options.max_axis_deviation_deg, _crease_half_angles_deg(build, edges, adj))
    for k in range(options.axis_smoothing_passes):
        out = 0.5 * out + 0.5 * (adj @ out) / np.maximum(deg, 1.0)
        out = limit_deviation(out, build, allowed)
        axes = tilts.hold(nodes, out)
        if k + 1 >= MIN_SMOOTHING_PASSES and np.einsum("ij,ij->i", axes[edges[:, 0]], axes[edges[:, 1]]).min() \
                >= cos_limit:
            break
    return axes


def plate_blend(height_mm: np.ndarray, first_layer_mm: float, blend_mm: float) -> np.ndarray:
    """The weight of the curved field at each height over the plate: 0 up to the first layer's top (which is
    then a plane), 1 from ``blend_mm`` up, a smoothstep between (its slope is 0 at both ends, so the layers
    bend gently)."""
    if blend_mm <= first_layer_mm:
        return np.where(height_mm <= first_layer_mm, 0.0, 1.0) if blend_mm > 0.0 else np.ones_like(height_mm)
    t = np.clip((height_mm - first_layer_mm) / (blend_mm - first_layer_mm), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def build_field(mesh: TetMesh, options: CurvedOptions, nominal_mm: float, side_margin_mm: float,
                first_layer_mm: float, tilts: TiltLimits | None = None) -> LayerField:
    """Solve the core and band fields on ``mesh`` (a tetrahedralised part) and derive the nozzle axes, each no
    more tilted than ``tilts`` allows (default: the options' limit and the plate's rule)."""
    ops = fem_operators(mesh)
    base = base_nodes(mesh.nodes)
    if len(base) == 0:
        raise MeshError("curved slicing: the part does not touch the plate", reason="no_base")
    height = mesh.nodes[:, 2] - float(mesh.nodes[:, 2].min())
    w = plate_blend(height, first_layer_mm, options.plate_blend_mm)
    geodesic = round_creases(mesh, ops, geodesic_distance(mesh, ops, base, options.heat_time_r),
                             options.crease_flatten_r, options.crease_width_mm)
    if tilts is None:
        tilts = TiltLimits(float(mesh.nodes[:, 2].min()), first_layer_mm, options.tip_radius_mm, options.max_tilt_deg)
    d_base = limit_lean(mesh, ops, w * geodesic + (1.0 - w) * height, base, tilts)
    core_dir = unit_rows(node_gradients(ops, mesh.tets, d_base))
    core_grad = node_gradient_norms(ops, mesh.tets, d_base)
    n = len(mesh.nodes)
    band = build_band(mesh, ops, d_base, options, tilts, margin_mm=max(side_margin_mm, 2.0 * nominal_mm *
                                                                       options.top_band_layers))
    band_mm = options.top_band_layers * nominal_mm if band is not None else 0.0
    if band is not None and band_mm > 0.0:
        d_top, band_dir, band_grad, followed = band.g_mm, band.direction, band.grad_r, band.followed
        clip = d_top - band_mm
    else:
        d_top = np.full(n, np.inf)
        band_dir, band_grad = core_dir, core_grad
        clip = np.full(n, np.inf)
        followed = np.zeros(len(mesh.boundary_faces()[0]), dtype=bool)
    in_band = clip < 0.0
    build = np.where(in_band[:, None], band_dir, core_dir)
    axis = _nozzle_axes(build, mesh.edges, mesh.nodes, tilts, options)
    return LayerField(mesh=mesh, ops=ops, d_base_mm=d_base, d_top_mm=d_top, band_mm=band_mm, core_dir=core_dir,
                      core_grad_r=core_grad, band_dir=band_dir, band_grad_r=band_grad, axis=axis, in_band=in_band,
                      band_clip_mm=clip, followed=followed, under_top_mm=under_tops_mm(mesh, core_dir, followed))
