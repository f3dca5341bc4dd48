"""Model loading from bytes (STL ascii/binary, OBJ, 3MF) and safe mesh repair.

The slicer service receives a model as bytes over the network, so everything
here works on ``bytes`` plus the original file name (whose suffix picks the
format; STL is sniffed as ascii or binary). The result is a watertight,
consistently wound :class:`trimesh.Trimesh` in millimetres, or a
:class:`MeshError` that names the file and the problem.

Repair is deliberately conservative: merging duplicate vertices, dropping
degenerate and duplicate triangles, fixing winding and inside-out shells and
closing *small* holes are safe, because they cannot change the printed shape
by more than the hole's own size. Edges shared by more than two triangles, or
holes too large to close without guessing the surface, are refused.
"""
from __future__ import annotations

import io
import re
from pathlib import PurePath

import numpy as np
import trimesh

from fabric.slicing.mesh3mf import read_3mf
from fabric.wire.errors import MeshError

__all__ = ["load_mesh", "repair_mesh", "MAX_HOLE_EDGES"]

# A hole is "small" (safe to close with a fan) below both of these.
MAX_HOLE_EDGES = 64
MAX_HOLE_SPAN_R = 0.05      # of the model's bounding-box diagonal
MIN_HOLE_SPAN_MM = 2.0      # ... but always allow holes up to this size

_STL_DTYPE = np.dtype([("normal", "<f4", (3,)), ("tri", "<f4", (3, 3)), ("attr", "<u2")])
_ASCII_VERTEX = re.compile(rb"vertex\s+(\S+)\s+(\S+)\s+(\S+)")


def load_mesh(data: bytes, filename: str) -> trimesh.Trimesh:
    """Parse a model from bytes and repair it where safe.

    ``filename``'s suffix selects the format (``.stl``, ``.obj``, ``.3mf``).
    Repair notes (what was fixed) are kept in ``mesh.metadata["repairs"]``.
    Raises MeshError (empty, truncated, unreadable, or not repairable).
    """
    suffix = PurePath(filename).suffix.lower()
    if not data:
        raise MeshError(f"{filename}: the file is empty", file=filename, reason="empty")
    if suffix == ".stl":
        triangles = _read_stl(data, filename)
        mesh = trimesh.Trimesh(vertices=triangles.reshape(-1, 3),
                               faces=np.arange(len(triangles) * 3).reshape(-1, 3), process=False)
    elif suffix == ".obj":
        mesh = _read_obj(data, filename)
    elif suffix == ".3mf":
        vertices, faces = read_3mf(data, filename)
        mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    else:
        raise MeshError(f"{filename}: unsupported model format {suffix or '(no suffix)'!r}; "
                        "use .stl, .obj or .3mf", file=filename, reason="format")
    return repair_mesh(mesh, filename)


def _read_stl(data: bytes, filename: str) -> np.ndarray:
    """Triangles (n, 3, 3) float64 from an ascii or binary STL."""
    n_bin = int.from_bytes(data[80:84], "little") if len(data) >= 84 else -1
    if n_bin >= 0 and len(data) == 84 + 50 * n_bin:
        if n_bin == 0:
            raise MeshError(f"{filename}: binary STL with no triangles", file=filename, reason="empty")
        rec = np.frombuffer(data, dtype=_STL_DTYPE, count=n_bin, offset=84)
        return rec["tri"].astype(np.float64)
    head = data[:512].lstrip().lower()
    if head.startswith(b"solid") and (b"facet" in data[:4096].lower() or len(data) < 4096):
        return _read_ascii_stl(data, filename)
    if n_bin > 0 and len(data) < 84 + 50 * n_bin:
        raise MeshError(f"{filename}: truncated binary STL (or not an STL at all): header announces "
                        f"{n_bin} triangles ({84 + 50 * n_bin} bytes) but the file has {len(data)} bytes",
                        file=filename, reason="truncated", expected_bytes=84 + 50 * n_bin,
                        actual_bytes=len(data))
    raise MeshError(f"{filename}: not an STL file (neither ascii 'solid ... facet' nor a binary "
                    f"header matching its size)", file=filename, reason="format")


def _read_ascii_stl(data: bytes, filename: str) -> np.ndarray:
    """Parse the ``vertex x y z`` lines of an ascii STL (vectorised float parse)."""
    coords = _ASCII_VERTEX.findall(data)
    if not coords:
        raise MeshError(f"{filename}: ascii STL with no vertices", file=filename, reason="empty")
    tail = data.rstrip()[-200:].lower()
    if len(coords) % 3 != 0 or b"endsolid" not in tail:
        raise MeshError(f"{filename}: truncated ascii STL ({len(coords)} vertices, "
                        f"{'no closing endsolid' if b'endsolid' not in tail else 'not a multiple of 3'})",
                        file=filename, reason="truncated", vertices=len(coords))
    try:
        flat = np.array(coords, dtype=np.float64)
    except ValueError as exc:
        raise MeshError(f"{filename}: bad number in ascii STL: {exc}", file=filename,
                        reason="format") from None
    return flat.reshape(-1, 3, 3)


def _read_obj(data: bytes, filename: str) -> trimesh.Trimesh:
    """Wavefront OBJ through trimesh (scenes are flattened into one mesh)."""
    try:
        loaded = trimesh.load(io.BytesIO(data), file_type="obj", force="mesh", process=False)
    except (ValueError, IndexError, KeyError, TypeError, UnicodeDecodeError) as exc:
        raise MeshError(f"{filename}: unreadable OBJ: {exc}", file=filename, reason="format") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshError(f"{filename}: OBJ has no triangles", file=filename, reason="empty")
    return loaded


def repair_mesh(mesh: trimesh.Trimesh, filename: str = "<mesh>") -> trimesh.Trimesh:
    """Make ``mesh`` watertight and consistently wound where that is safe, else raise MeshError."""
    notes: list[str] = []
    v = np.asarray(mesh.vertices, dtype=np.float64)
    if not np.isfinite(v).all():
        raise MeshError(f"{filename}: vertices with NaN or infinite coordinates", file=filename,
                        reason="non-finite")
    n0 = len(mesh.faces)
    mesh = trimesh.Trimesh(vertices=v, faces=np.asarray(mesh.faces), process=False)
    mesh.merge_vertices(digits_vertex=6)
    mesh.update_faces(mesh.nondegenerate_faces(height=1e-9))
    if len(mesh.faces) == 0:
        raise MeshError(f"{filename}: all {n0} triangles are degenerate (zero area)", file=filename,
                        reason="degenerate", faces=n0)
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) < n0:
        notes.append(f"removed {n0 - len(mesh.faces)} degenerate or duplicate triangles")
    extent = mesh.bounds[1] - mesh.bounds[0]
    if (extent < 1e-6).any():
        raise MeshError(f"{filename}: the model is flat (extent {extent.round(3).tolist()} mm)",
                        file=filename, reason="degenerate", extent_mm=extent.tolist())
    # Edges shared by more than two triangles: no safe way to tell inside from outside.
    counts = _edge_use_counts(mesh)
    if (counts > 2).any():
        bad = int((counts > 2).sum())
        raise MeshError(f"{filename}: non-manifold mesh: {bad} edges are shared by more than two "
                        "triangles; fix the model in a CAD/mesh tool", file=filename,
                        reason="non-manifold", edges=bad)
    if (counts == 1).any():
        mesh, filled = _close_small_holes(mesh, filename)
        notes.append(f"closed {filled} small holes")
    if not mesh.is_winding_consistent:
        trimesh.repair.fix_winding(mesh)
        notes.append("fixed inconsistent triangle winding")
    if not mesh.is_watertight or not mesh.is_winding_consistent:
        raise MeshError(f"{filename}: the mesh is not a closed surface and could not be repaired "
                        "safely", file=filename, reason="open")
    if mesh.volume < 0:
        mesh.invert()
        notes.append("turned inside-out shells right side out")
    if mesh.volume <= 1e-9:
        raise MeshError(f"{filename}: the mesh encloses no volume", file=filename, reason="degenerate")
    mesh.metadata["repairs"] = notes
    mesh.metadata["file"] = filename
    return mesh


def _edge_keys(edges: np.ndarray, n_vertices: int) -> np.ndarray:
    """One int64 per undirected edge (a 1-D key sorts ~10x faster than unique rows)."""
    lo = np.minimum(edges[:, 0], edges[:, 1]).astype(np.int64)
    hi = np.maximum(edges[:, 0], edges[:, 1]).astype(np.int64)
    return lo * n_vertices + hi


def _edge_use_counts(mesh: trimesh.Trimesh) -> np.ndarray:
    """How many triangles use each undirected edge."""
    _, counts = np.unique(_edge_keys(mesh.edges, len(mesh.vertices)), return_counts=True)
    return counts


def _close_small_holes(mesh: trimesh.Trimesh, filename: str) -> tuple[trimesh.Trimesh, int]:
    """Fan-fill every boundary loop that is small; refuse when any loop is not.

    Boundary edges are the directed edges used by one triangle. Following them
    head to tail gives the hole loops; each is closed with a fan around its
    centroid, wound opposite to the boundary so the patch agrees with the
    surrounding triangles.
    """
    edges = mesh.edges                      # directed, (3F, 2)
    _, inv, counts = np.unique(_edge_keys(edges, len(mesh.vertices)), return_inverse=True, return_counts=True)
    boundary = edges[counts[inv.ravel()] == 1]
    nxt = {int(a): int(b) for a, b in boundary}
    if len(nxt) != len(boundary):
        raise MeshError(f"{filename}: open mesh whose holes touch each other at a vertex; "
                        "cannot close safely", file=filename, reason="open")
    diag = float(np.linalg.norm(mesh.bounds[1] - mesh.bounds[0]))
    span_limit = max(MIN_HOLE_SPAN_MM, MAX_HOLE_SPAN_R * diag)
    vertices = [np.asarray(mesh.vertices)]
    faces = [np.asarray(mesh.faces)]
    n_vert = len(mesh.vertices)
    loops = 0
    while nxt:
        start, cur = nxt.popitem()
        loop = [start]
        while cur != start:
            loop.append(cur)
            if cur not in nxt:
                raise MeshError(f"{filename}: open mesh with a boundary that does not close",
                                file=filename, reason="open")
            cur = nxt.pop(cur)
            if len(loop) > MAX_HOLE_EDGES:
                break
        pts = mesh.vertices[loop]
        span = float(np.ptp(pts, axis=0).max())
        if len(loop) > MAX_HOLE_EDGES or span > span_limit:
            edges = f"more than {MAX_HOLE_EDGES}" if len(loop) > MAX_HOLE_EDGES else str(len(loop))
            raise MeshError(f"{filename}: open mesh: a hole of {edges} edges spanning "
                            f"{span:.2f} mm is too large to close safely (limit {MAX_HOLE_EDGES} edges, "
                            f"{span_limit:.2f} mm)", file=filename, reason="open", hole_edges=len(loop),
                            hole_span_mm=span)
        centre = n_vert
        vertices.append(pts.mean(axis=0, keepdims=True))
        n_vert += 1
        ring = np.asarray(loop)
        # boundary edge a->b belongs to an existing triangle as a->b; the patch uses b->a.
        faces.append(np.column_stack([np.roll(ring, -1), ring, np.full(len(ring), centre)]))
        loops += 1
    out = trimesh.Trimesh(vertices=np.vstack(vertices), faces=np.vstack(faces), process=False)
    out.update_faces(out.nondegenerate_faces(height=1e-12))
    return out, loops
