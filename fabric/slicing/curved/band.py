"""The top band: the last layers, which follow the part's top where the nozzle can lie along its normal and
run on straight past it, so that nothing printed before them stands beside them.

Why not the distance from the top. Its level sets follow the top faces and
then wrap round their edges into the part, so the band had to be cut off: a
margin from the side walls (where the core's layers climbed the wall to the
top) and, for a top running down to the plate (a dome's rim), somewhere above
the plate. Everything the core laid beside such a cut is older than the band
and as high as it, and the nozzle's tip (a disc 2 mm across on the multi-axis
cell, five beads wide) reaches over it while laying the band's edge: the
collision check finds the tip in the core's beads at every cut. The band's
only boundary inside the part must be its bottom, which is one of its own
level sets: the core then lies under the band everywhere.

The band field ``g`` here is 0 on the *followed* top faces and grows into the
part with its gradient as close as the least squares allow (:func:`.heat.fit_potential`)
to a direction field ``X``: the normal of the nearest followed faces, so past
the followed faces the band's layers run on straight (in the followed faces'
last direction) until they leave the part through its surface. A face is
followed when it faces up no further from +z than the nozzle may tilt there
(:class:`.axis.TiltLimits`: so the band's layers flatten towards the plate
as the nozzle must, and lean no further than the cell's arm holds) and
``top_slope_deg``; ``X`` is limited to the same tilt at each element. Where the band's layers would overhang a side wall
(a wall leaning out further than 45 degrees from them, as round a frustum's
top) ``X`` turns to the core's build direction within ``margin`` of the wall
and the top faces there are not followed: the band's layers bend down with
the core's and leave through the top instead.

Only the part's tops are followed. Faces that face up but have the part rise
above them (a cup's floor inside its walls, the ledge round the sample part's
boss) are not the top: a band under them has its layers run on into the
material beside them, which then lies above the band's top (``g < 0``) and
was neither band nor core (the sample part's curved slice laid 18 layers of a
100-layer cup). A connected patch of followed faces is kept only when no node
of the part stands more than ``TOP_TOLERANCE_MM`` above the patch's highest
point within ``margin`` of it (in plan view), after the faces near walls are
let go (what is left of a flaring lip's inside is no top: the lip rises over
it); the core lays the rest, as planar layers would.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from fabric.slicing.curved.axis import TiltLimits, unit_rows
from fabric.slicing.curved.heat import (
    FemOperators,
    edge_distance,
    fit_potential,
    node_gradient_norms,
    node_gradients,
    tet_gradients,
)
from fabric.slicing.curved.options import CurvedOptions
from fabric.slicing.curved.tetmesh import TetMesh

__all__ = ["Band", "build_band", "followed_faces", "top_patches"]

NEAREST_FACES = 8            # followed faces whose normals (inverse-square distance weighted) give X
TOP_TOLERANCE_MM = 0.5       # a node this much above a patch's highest point, beside it: the patch is not the top
SIN45 = math.sin(math.radians(45.0))


@dataclass(frozen=True)
class Band:
    """The band field and what it follows (arrays per node, ``followed`` per boundary face)."""

    g_mm: np.ndarray             # 0 on the followed faces, growing into the part
    direction: np.ndarray        # (n, 3) unit -grad g: the band's layer normal
    grad_r: np.ndarray           # (n,) |grad g|, mean over the adjacent elements
    followed: np.ndarray         # (f,) bool over mesh.boundary_faces(): the faces the band's top layer is


def followed_faces(mesh: TetMesh, options: CurvedOptions, tilts: TiltLimits) -> np.ndarray:
    """(f,) the boundary faces the band follows: off the plate, facing up no further from +z than the nozzle may
    tilt at their lowest corner (``tilts``, along the way the face leans) and ``top_slope_deg``."""
    faces, normals = mesh.boundary_faces()
    z = mesh.nodes[:, 2]
    zmin = float(z.min())
    on_plate = np.all(z[faces] <= zmin + 0.02, axis=1)
    tilt = np.degrees(np.arccos(np.clip(normals[:, 2], -1.0, 1.0)))
    low = mesh.nodes[faces].mean(axis=1)
    low[:, 2] = z[faces].min(axis=1)
    limit = np.minimum(tilts.deg(low, normals), options.top_slope_deg)
    return (tilt <= limit) & ~on_plate


def top_patches(mesh: TetMesh, faces: np.ndarray, followed: np.ndarray, margin_mm: float) -> np.ndarray:
    """(f,) ``followed`` less the patches (faces connected through their corners) that have the part rising
    above them within ``margin_mm`` in plan view (module docstring: only the part's tops are followed)."""
    idx = np.flatnonzero(followed)
    if len(idx) == 0:
        return followed
    corners = faces[idx]
    # faces sharing a node are one patch: a graph of the followed faces through their nodes
    n_nodes = len(mesh.nodes)
    rows = np.repeat(np.arange(len(idx)), 3)
    incidence = sp.csr_matrix((np.ones(len(rows)), (rows, corners.ravel())), shape=(len(idx), n_nodes))
    n_patches, label = connected_components(incidence @ incidence.T, directed=False)
    z = mesh.nodes[:, 2]
    out = followed.copy()
    for k in range(n_patches):
        mine = idx[label == k]
        nodes = np.unique(faces[mine].ravel())
        top = float(z[nodes].max())
        higher = np.flatnonzero(z > top + TOP_TOLERANCE_MM)
        if len(higher) == 0:
            continue
        dist, _i = cKDTree(mesh.nodes[nodes, :2]).query(mesh.nodes[higher, :2], distance_upper_bound=margin_mm)
        if np.any(np.isfinite(dist)):
            out[mine] = False
    return out


def _nearest_normals(centres: np.ndarray, normals: np.ndarray, areas: np.ndarray, at: np.ndarray) -> np.ndarray:
    """(k, 3) unit mean of the normals of the faces (``centres``) nearest each point of ``at``, weighted by
    area over squared distance."""
    k = min(NEAREST_FACES, len(centres))
    dist, idx = cKDTree(centres).query(at, k=k)
    dist, idx = dist.reshape(len(at), k), idx.reshape(len(at), k)
    w = areas[idx] / np.maximum(dist, 1e-6) ** 2
    return unit_rows(np.einsum("ik,ikj->ij", w, normals[idx]))


def build_band(mesh: TetMesh, ops: FemOperators, core_field: np.ndarray, options: CurvedOptions,
               tilts: TiltLimits, margin_mm: float) -> Band | None:
    """The band field of ``mesh`` (module docstring), or None when no face can be followed.

    ``core_field`` is the core's layer field (its gradient is the direction the band bends to at walls it
    would overhang); ``margin_mm`` how far from such walls it does.
    """
    faces, normals = mesh.boundary_faces()
    followed = followed_faces(mesh, options, tilts)
    if not np.any(followed):
        return None
    p = mesh.nodes[faces]
    centres = p.mean(axis=1)
    areas = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    zmin = float(mesh.nodes[:, 2].min())
    on_plate = np.all(p[:, :, 2] <= zmin + 0.02, axis=1)
    # walls the band would overhang: not followed, off the plate, leaning out past 45 degrees from X there
    x_face = _nearest_normals(centres[followed], normals[followed], areas[followed], centres)
    wall = ~followed & ~on_plate & (np.einsum("ij,ij->i", normals, x_face) < -SIN45)
    tet_c = mesh.nodes[mesh.tets].mean(axis=1)
    x = _nearest_normals(centres[followed], normals[followed], areas[followed], tet_c)
    if np.any(wall):
        near, _ = cKDTree(centres[wall]).query(tet_c, distance_upper_bound=margin_mm)
        w = np.clip(1.0 - np.asarray(near) / margin_mm, 0.0, 1.0)
        core = unit_rows(tet_gradients(ops, mesh.tets, core_field))
        x = unit_rows((1.0 - w)[:, None] * x + w[:, None] * core)
        face_near, _ = cKDTree(centres[wall]).query(centres, distance_upper_bound=margin_mm)
        followed = followed & ~np.isfinite(face_near)
    followed = top_patches(mesh, faces, followed, margin_mm)       # what is left of a top may be no top
    if not np.any(followed):
        return None
    x = tilts.hold(tet_c, x)
    sources = np.unique(faces[followed].ravel())
    g = fit_potential(mesh, ops, -x, sources, edge_distance(mesh, sources))
    direction = unit_rows(-node_gradients(ops, mesh.tets, g))
    return Band(g, direction, node_gradient_norms(ops, mesh.tets, g), followed)
