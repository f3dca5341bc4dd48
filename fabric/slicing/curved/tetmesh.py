"""Tetrahedralisation of a placed part: the volume mesh the layer fields live on.

The fields are smooth, so the volume mesh does not need the resolution of the
part's surface, only about one lattice pitch everywhere (the pitch that puts
``interior_nodes`` lattice points in the part's volume). It is built in four
steps:

1. *simplify* the surface within ``tolerance_mm`` (manifold3d's edge
   collapses keep a subset of the input vertices and move no surface by more
   than the tolerance; PrusaSlicer's default slice resolution is 0.0125 mm):
   a 100k-triangle dome keeps about 18k triangles;
2. *refine* it so no edge is longer than the pitch (long thin CAD triangles
   would otherwise give needle tetrahedra and coarse layer outlines);
3. *fill* the inside with a body-centred cubic lattice of that pitch,
   keeping the points about half a pitch from the surface (inside and
   distance both from rays cast along x, y and z through the lattice);
4. *connect* surface and lattice with TetGen's constrained Delaunay
   tetrahedralisation (switch ``p``: the surface is recovered, no refinement).

TetGen's own quality refinement (``q``) of the 100k triangles themselves gave
150k nodes in 19-26 s (points on a sphere are its worst case); of the
simplified surface it still took 8-13 s (most of it splitting the surface's
slivers), against about 1 s for these steps.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import trimesh

from fabric.wire.errors import MeshError

__all__ = ["TetMesh", "tetrahedralise", "lattice_pitch_mm", "SURFACE_TOLERANCE_MM"]

TETGEN_LEFTOVERS = ("_skipped.face", "_skipped.node")
SURFACE_TOLERANCE_MM = 0.0125     # how far simplification may move the surface
KEEP_AWAY_R = 0.5                 # lattice points closer to the surface than this many pitches are dropped
GRID_SHIFT_R = 0.5 + 0.0123       # lattice offset from the bounding box (in pitches): off any round coordinate


@dataclass(frozen=True)
class TetMesh:
    """A tetrahedral mesh of the part (mm, plate frame).

    ``nodes[:n_surface]`` are the vertices of the meshed surface (the part's
    surface simplified within ``surface_error_mm``, then refined: every vertex
    it kept from the input has its exact input coordinates); the rest are
    interior lattice points and any point TetGen added.
    """

    nodes: np.ndarray          # (n, 3) float64
    tets: np.ndarray           # (m, 4) int64, positively oriented
    n_surface: int             # the first n_surface nodes are the meshed surface's vertices
    surface_error_mm: float = 0.0    # how far the meshed surface may be from the input's

    @cached_property
    def edges(self) -> np.ndarray:
        """Unique undirected edges (k, 2), lower index first."""
        pairs = self.tets[:, [0, 0, 0, 1, 1, 2, 1, 2, 3, 2, 3, 3]].reshape(-1, 2, 6).transpose(0, 2, 1)
        pairs = np.sort(pairs.reshape(-1, 2), axis=1)
        n = np.int64(len(self.nodes))
        key = np.unique(pairs[:, 0] * n + pairs[:, 1])            # one int64 key per edge: a fast 1-D unique
        return np.column_stack([key // n, key % n])

    def boundary_faces(self) -> tuple[np.ndarray, np.ndarray]:
        """The triangles on the part's surface (used by one tetrahedron) and their outward unit normals."""
        return self._boundary

    @cached_property
    def _boundary(self) -> tuple[np.ndarray, np.ndarray]:
        opposite = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])      # outward for a positive tet
        faces = self.tets[:, opposite].reshape(-1, 3)
        srt = np.sort(faces, axis=1)
        n = np.int64(len(self.nodes))
        key = (srt[:, 0] * n + srt[:, 1]) * n + srt[:, 2]        # fits int64 below 2 million nodes
        _uniq, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
        faces = faces[counts[inverse] == 1]
        p = self.nodes[faces]
        normals = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        return faces, normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)


def lattice_pitch_mm(volume_mm3: float, interior_nodes: int) -> float:
    """The pitch of a body-centred cubic lattice (two points per cube) with ``interior_nodes`` points in
    ``volume_mm3``."""
    return (2.0 * max(volume_mm3, 1e-9) / max(interior_nodes, 1)) ** (1.0 / 3.0)


def _simplified(mesh: trimesh.Trimesh, tolerance_mm: float, pitch_mm: float) -> tuple[trimesh.Trimesh, float]:
    """The surface simplified within ``tolerance_mm`` and refined to edges of at most ``pitch_mm``, and the
    tolerance it holds. A mesh manifold3d will not take (or a manifold3d before 3.0, without these steps)
    is meshed as given, with 0."""
    import manifold3d  # compiled, imported only by the curved slicer

    if not hasattr(manifold3d, "Mesh64"):
        return mesh, 0.0
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.uint64)
    solid = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=vertices, tri_verts=faces))
    if solid.status() != manifold3d.Error.NoError or solid.is_empty() or not hasattr(solid, "refine_to_length"):
        return mesh, 0.0
    error = 0.0
    if tolerance_mm > 0.0:
        solid = solid.simplify(tolerance_mm)
        error = tolerance_mm
    out = solid.refine_to_length(pitch_mm).to_mesh64()
    return trimesh.Trimesh(np.asarray(out.vert_properties)[:, :3], np.asarray(out.tri_verts, dtype=np.int64),
                           process=False), error


def _axis_crossings(tri: np.ndarray, axis: int, origin: np.ndarray, pitch: float, shape: tuple[int, ...],
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Where the lattice's lines along ``axis`` cross the surface: (line index, coordinate along the axis).

    ``tri`` (f, 3, 3) are the surface triangles, the lines pass through ``origin + pitch * (i, j)`` in the
    other two axes (``shape`` lines each way). A line through a shared edge or vertex is counted once per
    crossing (the rasteriser's top-left rule on the projected triangles, wound counter-clockwise).
    """
    a, b = [k for k in range(3) if k != axis]
    p = tri[:, :, [a, b]]
    area = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0])
    keep = area != 0.0                                      # edge-on triangles: their neighbours count the crossing
    tri, p, area = tri[keep], p[keep], area[keep]
    flip = area < 0.0
    tri[flip] = tri[flip][:, [0, 2, 1]]
    p[flip] = p[flip][:, [0, 2, 1]]
    area = np.abs(area)
    lo = np.ceil((p.min(axis=1) - origin[[a, b]]) / pitch).astype(np.int64)
    hi = np.floor((p.max(axis=1) - origin[[a, b]]) / pitch).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, np.array([shape[a], shape[b]]) - 1)
    ni, nj = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0), np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
    count = ni * nj
    owner = np.repeat(np.arange(len(tri)), count)
    if len(owner) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    local = np.arange(len(owner)) - np.repeat(np.cumsum(count) - count, count)
    i = lo[owner, 0] + local // nj[owner]
    j = lo[owner, 1] + local % nj[owner]
    q = origin[[a, b]] + pitch * np.column_stack([i, j])
    pp = p[owner]
    weights = []
    for k in range(3):                                      # edge k runs from vertex k+1 to k+2, opposite vertex k
        s, e = pp[:, (k + 1) % 3], pp[:, (k + 2) % 3]
        d = e - s
        w = d[:, 0] * (q[:, 1] - s[:, 1]) - d[:, 1] * (q[:, 0] - s[:, 0])
        top_left = (d[:, 1] < 0.0) | ((d[:, 1] == 0.0) & (d[:, 0] < 0.0))
        weights.append(np.where((w > 0.0) | ((w == 0.0) & top_left), w, -1.0))
    w = np.column_stack(weights)
    hit = np.all(w >= 0.0, axis=1)
    w = w[hit] / area[owner[hit], None]
    coord = np.einsum("mk,mk->m", w, tri[owner[hit], :, axis])
    line = i[hit] * shape[b] + j[hit]
    return line, coord


def _lattice(surface: trimesh.Trimesh, pitch: float) -> np.ndarray:
    """Body-centred cubic lattice points inside ``surface``, at least ``KEEP_AWAY_R`` pitches from it.

    Inside: a point is inside when an odd number of surface crossings lie below it along a lattice line,
    by a majority of the three axes (robust to a grazing line). Distance: the nearest crossing along the
    three lines through the point, at least ``KEEP_AWAY_R`` pitches, which keeps a point at least
    ``KEEP_AWAY_R / sqrt(3)`` pitches from a locally flat surface whatever its slope.
    """
    tri = np.asarray(surface.vertices)[np.asarray(surface.faces)]
    lo, hi = np.asarray(surface.bounds[0]), np.asarray(surface.bounds[1])
    out = []
    for shift in (GRID_SHIFT_R, GRID_SHIFT_R + 0.5):                      # the two cubic sub-lattices
        origin = lo + shift * pitch
        shape = tuple(int(v) for v in np.maximum(np.floor((hi - origin) / pitch) + 1, 1))
        idx = np.indices(shape).reshape(3, -1).T
        votes = np.zeros(len(idx), dtype=np.int64)
        near = np.full(len(idx), np.inf)
        for axis in range(3):
            a, b = [k for k in range(3) if k != axis]
            line, coord = _axis_crossings(tri, axis, origin, pitch, shape)
            if len(line) == 0:
                continue
            span = float(hi[axis] - lo[axis]) + 4.0 * pitch + 1.0      # keys of different lines never overlap
            keys = np.sort(line * span + (coord - lo[axis] + 2.0 * pitch))
            pline = idx[:, a] * shape[b] + idx[:, b]
            pkey = pline * span + (origin[axis] + pitch * idx[:, axis] - lo[axis] + 2.0 * pitch)
            first = np.searchsorted(keys, pline * span)
            last = np.searchsorted(keys, (pline + 1) * span)
            at = np.searchsorted(keys, pkey)
            votes += (at - first) % 2
            below = np.where(at > first, pkey - keys[np.maximum(at - 1, 0)], np.inf)
            above = np.where(at < last, keys[np.minimum(at, len(keys) - 1)] - pkey, np.inf)
            near = np.minimum(near, np.minimum(below, above))
        keep = (votes >= 2) & (near >= KEEP_AWAY_R * pitch)
        out.append(origin + pitch * idx[keep])
    return np.vstack(out)


def tetrahedralise(mesh: trimesh.Trimesh, interior_nodes: int = 6000,
                   tolerance_mm: float = SURFACE_TOLERANCE_MM) -> TetMesh:
    """Fill a watertight, consistently wound triangle mesh with tetrahedra (see the module docstring).

    ``interior_nodes`` sets the lattice pitch (about that many points inside the part); ``tolerance_mm``
    how far the simplified surface may stray (0: no simplification). Raises MeshError when the mesh is
    not a closed solid or TetGen cannot mesh it (self-intersections).
    """
    import tetgen  # a compiled extension: imported only by the curved slicer

    if not mesh.is_watertight or not mesh.is_winding_consistent or mesh.volume <= 0:
        raise MeshError("curved slicing needs a closed solid: the mesh is not watertight or not "
                        "consistently wound", reason="not_watertight", faces=int(len(mesh.faces)),
                        watertight=bool(mesh.is_watertight))
    pitch = lattice_pitch_mm(float(mesh.volume), interior_nodes)
    surface, error = _simplified(mesh, tolerance_mm, pitch)
    inner = _lattice(surface, pitch)
    points = np.vstack([np.asarray(surface.vertices, dtype=np.float64), inner])
    gen = tetgen.TetGen(points, np.asarray(surface.faces, dtype=np.int32))
    try:
        nodes, tets = gen.tetrahedralize(plc=True, quality=False, quiet=True)[:2]
    except RuntimeError as exc:
        for leftover in TETGEN_LEFTOVERS:        # TetGen dumps the offending faces into the working directory
            Path(leftover).unlink(missing_ok=True)
        raise MeshError(f"TetGen could not fill the part: {exc}", reason="tetgen") from exc
    if len(tets) == 0 or len(nodes) < len(surface.vertices):
        raise MeshError("TetGen produced no tetrahedra (self-intersecting or degenerate surface)", reason="tetgen")
    nodes = np.asarray(nodes, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    # orient every tetrahedron positively (the FEM gradients below assume it)
    p = nodes[tets]
    vol6 = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0])
    flip = vol6 < 0
    tets[flip] = tets[flip][:, [1, 0, 2, 3]]
    keep = np.abs(vol6) > 1e-12
    return TetMesh(nodes=nodes, tets=tets[keep], n_surface=int(len(surface.vertices)), surface_error_mm=error)
