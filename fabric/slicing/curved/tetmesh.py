"""Tetrahedralisation of a placed part: the volume mesh the layer fields live on."""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import trimesh

from fabric.wire.errors import MeshError

__all__ = ["TetMesh", "tetrahedralise"]

TETGEN_LEFTOVERS = ("_skipped.face", "_skipped.node")


@dataclass(frozen=True)
class TetMesh:
    """A tetrahedral mesh of the part (mm, plate frame).

    ``nodes[:n_surface]`` are the part's own surface vertices in their original
    order (the surface is preserved, not split), so a quantity on the nodes can
    be read back on the input triangles by vertex index.
    """

    nodes: np.ndarray          # (n, 3) float64
    tets: np.ndarray           # (m, 4) int64, positively oriented
    n_surface: int             # the first n_surface nodes are the input mesh's vertices

    @cached_property
    def edges(self) -> np.ndarray:
        """Unique undirected edges (k, 2), lower index first."""
        pairs = self.tets[:, [0, 0, 0, 1, 1, 2, 1, 2, 3, 2, 3, 3]].reshape(-1, 2, 6).transpose(0, 2, 1)
        pairs = np.sort(pairs.reshape(-1, 2), axis=1)
        return np.unique(pairs, axis=0)

    def boundary_faces(self) -> tuple[np.ndarray, np.ndarray]:
        """The triangles on the part's surface (used by one tetrahedron) and their outward unit normals."""
        return self._boundary

    @cached_property
    def _boundary(self) -> tuple[np.ndarray, np.ndarray]:
        opposite = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])      # outward for a positive tet
        faces = self.tets[:, opposite].reshape(-1, 3)
        key = np.sort(faces, axis=1)
        _uniq, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        faces = faces[counts[inverse.ravel()] == 1]
        p = self.nodes[faces]
        normals = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        return faces, normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)


def _target_volume_mm3(mesh: trimesh.Trimesh, nodes_wanted: int) -> float:
    """The largest tetrahedron volume that gives about ``nodes_wanted`` nodes inside the part."""
    return max(float(mesh.volume) / max(nodes_wanted, 1) * 6.0, 1e-3)


def tetrahedralise(mesh: trimesh.Trimesh, interior_nodes: int = 20000) -> TetMesh:
    """Fill a watertight, consistently wound triangle mesh with tetrahedra (TetGen).

    The boundary keeps every input vertex (numbered first) and its shape; the interior is
    refined to a bounded radius-edge ratio with about ``interior_nodes`` nodes,
    so the fields have resolution inside thick parts. Raises MeshError when the
    mesh is not a closed solid or TetGen cannot mesh it (self-intersections).
    """
    import tetgen  # a compiled extension: imported only by the curved slicer

    if not mesh.is_watertight or not mesh.is_winding_consistent or mesh.volume <= 0:
        raise MeshError("curved slicing needs a closed solid: the mesh is not watertight or not "
                        "consistently wound", reason="not_watertight", faces=int(len(mesh.faces)),
                        watertight=bool(mesh.is_watertight))
    gen = tetgen.TetGen(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int32))
    try:
        nodes, tets = gen.tetrahedralize(quality=True, minratio=1.5, fixedvolume=True,
                                         maxvolume=_target_volume_mm3(mesh, interior_nodes))[:2]
    except RuntimeError as exc:
        for leftover in TETGEN_LEFTOVERS:        # TetGen dumps the offending faces into the working directory
            Path(leftover).unlink(missing_ok=True)
        raise MeshError(f"TetGen could not fill the part: {exc}", reason="tetgen") from exc
    if len(tets) == 0 or len(nodes) < len(mesh.vertices):
        raise MeshError("TetGen produced no tetrahedra (self-intersecting or degenerate surface)", reason="tetgen")
    nodes = np.asarray(nodes, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    # orient every tetrahedron positively (the FEM gradients below assume it)
    p = nodes[tets]
    vol6 = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0])
    flip = vol6 < 0
    tets[flip] = tets[flip][:, [1, 0, 2, 3]]
    keep = np.abs(vol6) > 1e-12
    return TetMesh(nodes=nodes, tets=tets[keep], n_surface=int(len(mesh.vertices)))
