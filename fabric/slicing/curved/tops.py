"""How far under the part's tops each node of the volume mesh lies, where the top band does not lay them.

The band (:mod:`.band`) lays the last layers under the tops it follows, solid.
Tops it does not follow (a ledge with the part rising beside it, a cup's
floor, the rim of a flaring lip) end core layers, which are sparse infill
inside their perimeters: without more, such a top would be left open. A core
layer is therefore solid within ``top_solid_layers`` layers of such a top
(:func:`.paths.layer_paths`), as a planar slicer's top layers are. A face is
such a top when it faces along the core's build direction (within
``TOP_SLOPE_DEG``): the layers end on it.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from fabric.slicing.curved.axis import unit_rows
from fabric.slicing.curved.tetmesh import TetMesh

__all__ = ["under_tops_mm", "TOP_SLOPE_DEG"]

TOP_SLOPE_DEG = 60.0            # a face this near the build direction ends the layers on it
FACE_SAMPLES = ((1 / 3, 1 / 3, 1 / 3), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0),
                (0.5, 0.5, 0.0), (0.0, 0.5, 0.5), (0.5, 0.0, 0.5))        # barycentric points of each face


def under_tops_mm(mesh: TetMesh, build_dir: np.ndarray, followed: np.ndarray) -> np.ndarray:
    """(n,) each node's distance (mm) from the nearest top the band does not follow (``followed``, over
    ``mesh.boundary_faces()``); inf without such tops."""
    faces, normals = mesh.boundary_faces()
    along = unit_rows(build_dir[faces].mean(axis=1))
    top = (np.einsum("ij,ij->i", normals, along) > math.cos(math.radians(TOP_SLOPE_DEG))) & ~followed
    if not np.any(top):
        return np.full(len(mesh.nodes), np.inf)
    corners = mesh.nodes[faces[top]]                                  # (k, 3, 3)
    weights = np.asarray(FACE_SAMPLES)                                # (s, 3)
    samples = np.einsum("sc,kcj->ksj", weights, corners).reshape(-1, 3)
    dist, _i = cKDTree(samples).query(mesh.nodes)
    return np.asarray(dist)
