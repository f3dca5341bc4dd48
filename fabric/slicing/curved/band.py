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
(:func:`.axis.plate_tilt_deg`: so the band's layers flatten towards the plate
as the nozzle must) and ``top_slope_deg``; ``X`` is limited to the same tilt
at each element's height. Where the band's layers would overhang a side wall
(a wall leaning out further than 45 degrees from them, as round a frustum's
top) ``X`` turns to the core's build direction within ``margin`` of the wall
and the top faces there are not followed: the band's layers bend down with
the core's and leave through the top instead.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from fabric.slicing.curved.axis import limit_tilt, plate_tilt_deg, unit_rows
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

__all__ = ["Band", "build_band", "followed_faces"]

NEAREST_FACES = 8            # followed faces whose normals (inverse-square distance weighted) give X
SIN45 = math.sin(math.radians(45.0))


@dataclass(frozen=True)
class Band:
    """The band field and what it follows (arrays per node, ``followed`` per boundary face)."""

    g_mm: np.ndarray             # 0 on the followed faces, growing into the part
    direction: np.ndarray        # (n, 3) unit -grad g: the band's layer normal
    grad_r: np.ndarray           # (n,) |grad g|, mean over the adjacent elements
    followed: np.ndarray         # (f,) bool over mesh.boundary_faces(): the faces the band's top layer is


def followed_faces(mesh: TetMesh, options: CurvedOptions, first_layer_mm: float) -> np.ndarray:
    """(f,) the boundary faces the band follows: off the plate, facing up no further from +z than the nozzle may
    tilt at their lowest corner's height (and ``top_slope_deg``)."""
    faces, normals = mesh.boundary_faces()
    z = mesh.nodes[:, 2]
    zmin = float(z.min())
    on_plate = np.all(z[faces] <= zmin + 0.02, axis=1)
    tilt = np.degrees(np.arccos(np.clip(normals[:, 2], -1.0, 1.0)))
    limit = np.minimum(plate_tilt_deg(z[faces].min(axis=1) - zmin, first_layer_mm, options.tip_radius_mm,
                                      options.max_tilt_deg), options.top_slope_deg)
    return (tilt <= limit) & ~on_plate


def _nearest_normals(centres: np.ndarray, normals: np.ndarray, areas: np.ndarray, at: np.ndarray) -> np.ndarray:
    """(k, 3) unit mean of the normals of the faces (``centres``) nearest each point of ``at``, weighted by
    area over squared distance."""
    k = min(NEAREST_FACES, len(centres))
    dist, idx = cKDTree(centres).query(at, k=k)
    dist, idx = dist.reshape(len(at), k), idx.reshape(len(at), k)
    w = areas[idx] / np.maximum(dist, 1e-6) ** 2
    return unit_rows(np.einsum("ik,ikj->ij", w, normals[idx]))


def build_band(mesh: TetMesh, ops: FemOperators, core_field: np.ndarray, options: CurvedOptions,
               first_layer_mm: float, margin_mm: float) -> Band | None:
    """The band field of ``mesh`` (module docstring), or None when no face can be followed.

    ``core_field`` is the core's layer field (its gradient is the direction the band bends to at walls it
    would overhang); ``margin_mm`` how far from such walls it does.
    """
    faces, normals = mesh.boundary_faces()
    followed = followed_faces(mesh, options, first_layer_mm)
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
    tilt = plate_tilt_deg(tet_c[:, 2] - zmin, first_layer_mm, options.tip_radius_mm, options.max_tilt_deg)
    if np.any(wall):
        near, _ = cKDTree(centres[wall]).query(tet_c, distance_upper_bound=margin_mm)
        w = np.clip(1.0 - np.asarray(near) / margin_mm, 0.0, 1.0)
        core = unit_rows(tet_gradients(ops, mesh.tets, core_field))
        x = unit_rows((1.0 - w)[:, None] * x + w[:, None] * core)
        face_near, _ = cKDTree(centres[wall]).query(centres, distance_upper_bound=margin_mm)
        followed = followed & ~np.isfinite(face_near)
        if not np.any(followed):
            return None
    x = limit_tilt(x, tilt)
    sources = np.unique(faces[followed].ravel())
    g = fit_potential(mesh, ops, -x, sources, edge_distance(mesh, sources))
    direction = unit_rows(-node_gradients(ops, mesh.tets, g))
    return Band(g, direction, node_gradient_norms(ops, mesh.tets, g), followed)
