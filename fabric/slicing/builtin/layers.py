"""Layer heights and the vectorised mesh section: every layer's outline as shapely polygons.

Heights follow PrusaSlicer: the first layer is ``first_layer_height_mm``
thick, every other layer ``layer_height_mm``, and a layer exists while its
mid-height is below the top of the part. Each layer is cut at its mid-height.

The section is computed for all layers at once. A vertex is *above* a plane
when ``z >= z_plane`` (so a flat top lying exactly on a cutting plane still
counts as material, as in PrusaSlicer); an edge crosses the plane when its two ends are on
different sides, and a triangle spanning the plane then has exactly two
crossing edges, joined by one segment. Because the side test is per vertex,
neighbouring triangles agree on every crossing, so each crossing point is
identified by (plane, edge) and the segments chain head to tail into closed
rings. Segments are oriented from the triangle's "falling" edge to its
"rising" edge (following the triangle's winding), which makes outer
boundaries counter-clockwise and holes clockwise when the mesh's normals
point outwards. Rings are put in order by pointer jumping (list ranking),
so no Python loop runs per segment.
"""
from __future__ import annotations

import numpy as np
import shapely
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

__all__ = ["layer_heights", "section_rings", "rings_to_polygons"]


def layer_heights(top_mm: float, layer_mm: float, first_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(print_z, thickness) of every layer for a part ``top_mm`` tall (PrusaSlicer's rule).

    The height is accumulated by repeated addition, exactly as PrusaSlicer
    does, so a layer whose mid-height lands on the top of the part within
    rounding is kept or dropped the same way in both slicers.
    """
    tops = [first_mm]
    print_z = first_mm
    while print_z + 0.5 * layer_mm < top_mm:
        print_z += layer_mm
        tops.append(print_z)
    out = np.asarray(tops, dtype=np.float64)
    thick = np.full(len(out), layer_mm)
    thick[0] = first_mm
    return out, thick


def section_rings(mesh: trimesh.Trimesh, planes_z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Cut ``mesh`` by every plane in ``planes_z`` (ascending).

    Returns ``(xy, ring_start, ring_plane, open_chains)``: ``xy`` holds the ring
    vertices back to back, ring ``r`` is ``xy[ring_start[r]:ring_start[r + 1]]``
    (``ring_start`` has one extra closing entry) on plane ``ring_plane[r]``.
    ``open_chains`` counts chains of segments that do not close into a ring
    (0 on a closed mesh); they are dropped.
    """
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    edge_of = np.asarray(mesh.faces_unique_edges, dtype=np.int64)   # face edge j: (f[j], f[j+1])
    n_edges = len(mesh.edges_unique)
    z = v[:, 2]
    fz = z[f]
    lo = np.searchsorted(planes_z, fz.min(axis=1), side="right")      # first plane > zmin
    hi = np.searchsorted(planes_z, fz.max(axis=1), side="right")      # planes <= zmax
    count = np.maximum(hi - lo, 0)
    total = int(count.sum())
    if total == 0:
        return np.zeros((0, 2)), np.zeros(1, np.int64), np.zeros(0, np.int64), 0
    face = np.repeat(np.arange(len(f)), count)
    offset = np.repeat(np.cumsum(count) - count, count)
    plane = lo[face] + (np.arange(total) - offset)
    zp = planes_z[plane]
    tri = f[face]                                      # (n, 3) vertex ids
    above = z[tri] >= zp[:, None]                      # (n, 3)
    nxt_above = np.roll(above, -1, axis=1)             # side of the edge's head vertex
    rising = ~above & nxt_above                        # edge j goes below -> above
    falling = above & ~nxt_above
    j_rise = np.argmax(rising, axis=1)
    j_fall = np.argmax(falling, axis=1)
    rows = np.arange(total)

    def crossing(j: np.ndarray) -> np.ndarray:
        a = v[tri[rows, j]]
        b = v[tri[rows, (j + 1) % 3]]
        t = (zp - a[:, 2]) / (b[:, 2] - a[:, 2])
        return a[:, :2] + t[:, None] * (b[:, :2] - a[:, :2])

    # Each segment runs from the crossing on the triangle's falling edge (above ->
    # below in winding order) to the one on its rising edge: with outward normals
    # that goes counter-clockwise around material seen from above.
    start_pt = crossing(j_fall)
    start_key = plane * n_edges + edge_of[face, j_fall]
    end_key = plane * n_edges + edge_of[face, j_rise]
    order = np.argsort(start_key, kind="stable")
    pos = np.searchsorted(start_key[order], end_key)
    pos = np.minimum(pos, total - 1)
    matched = start_key[order[pos]] == end_key
    nxt = np.where(matched, order[pos], -1)
    # Rings: components of the successor graph, ordered by list ranking.
    good = nxt >= 0
    graph = coo_matrix((np.ones(int(good.sum())), (rows[good], nxt[good])), shape=(total, total))
    n_comp, label = connected_components(graph, directed=True, connection="weak")
    root = np.full(n_comp, total, dtype=np.int64)
    np.minimum.at(root, label, rows)
    pred = np.full(total, -1, dtype=np.int64)
    pred[nxt[good]] = rows[good]
    cut = nxt.copy()
    is_root = root[label] == rows
    # break each cycle just before its root (or keep open chains as they are)
    root_pred = pred[rows[is_root]]
    cut[root_pred[root_pred >= 0]] = -1
    dist = (cut >= 0).astype(np.int64)
    ptr = cut.copy()
    while True:
        live = ptr >= 0
        if not live.any():
            break
        dist[live] += dist[ptr[live]]
        ptr[live] = ptr[ptr[live]]
    # a chain that is not a cycle has no well-defined ring: drop it
    closed = np.zeros(n_comp, dtype=bool)
    closed[label[rows[is_root]]] = pred[rows[is_root]] >= 0
    closed &= np.bincount(label, weights=(~good).astype(float), minlength=n_comp) == 0
    keep = closed[label]
    seq = np.lexsort((-dist[keep], label[keep]))
    idx = rows[keep][seq]
    xy = start_pt[idx]
    ring_label = label[idx]
    boundaries = np.flatnonzero(np.diff(ring_label)) + 1
    ring_start = np.concatenate([[0], boundaries, [len(idx)]]).astype(np.int64)
    ring_plane = plane[idx[ring_start[:-1]]] if len(idx) else np.zeros(0, np.int64)
    return xy, ring_start, ring_plane, int((~closed).sum())


def ring_signed_areas(xy: np.ndarray, ring_start: np.ndarray) -> np.ndarray:
    """Shoelace signed area of every ring (positive = counter-clockwise)."""
    if len(xy) == 0:
        return np.zeros(0)
    ring_id = np.repeat(np.arange(len(ring_start) - 1), np.diff(ring_start))
    nxt = np.arange(1, len(xy) + 1)
    nxt[ring_start[1:] - 1] = ring_start[:-1]
    cross = xy[:, 0] * xy[nxt, 1] - xy[nxt, 0] * xy[:, 1]
    return 0.5 * np.bincount(ring_id, weights=cross, minlength=len(ring_start) - 1)


def rings_to_polygons(xy: np.ndarray, ring_start: np.ndarray, ring_plane: np.ndarray,
                      n_planes: int, min_area_mm2: float = 1e-4) -> list[shapely.Geometry]:
    """Group rings per plane into (multi)polygons with holes.

    Counter-clockwise rings are outlines, clockwise rings holes. A hole belongs
    to the smallest outline that contains it, so islands inside holes inside
    outlines nest correctly; outlines that overlap (separate shells that
    intersect) are merged by a union, which matches the nonzero fill rule.
    """
    empty = shapely.Polygon()
    out: list[shapely.Geometry] = [empty] * n_planes
    if len(xy) == 0:
        return out
    area = ring_signed_areas(xy, ring_start)
    sizes = np.diff(ring_start)
    ok = (np.abs(area) > min_area_mm2) & (sizes >= 3)
    ring_id = np.repeat(np.arange(len(sizes)), sizes)
    sel = ok[ring_id]
    kept = np.flatnonzero(ok)
    rings = np.empty(len(sizes), dtype=object)
    rings[kept] = shapely.linearrings(xy[sel], indices=np.searchsorted(kept, ring_id[sel]))
    polys = np.empty(len(sizes), dtype=object)
    polys[kept] = shapely.polygons(rings[kept])
    by_plane = np.argsort(ring_plane[kept], kind="stable")
    kept = kept[by_plane]
    splits = np.flatnonzero(np.diff(ring_plane[kept])) + 1
    for group in np.split(kept, splits):
        if len(group) == 0:
            continue
        p = int(ring_plane[group[0]])
        outers = group[area[group] > 0]
        holes = group[area[group] < 0]
        if len(outers) == 0:
            continue
        if len(outers) == 1 and len(holes) == 0:
            geom = polys[outers[0]]
        else:
            geom = _assemble(outers, holes, rings, polys, area, xy, ring_start)
        if not shapely.is_valid(geom):
            geom = shapely.make_valid(geom)
            geom = shapely.union_all(shapely.get_parts(geom)[
                np.isin(shapely.get_type_id(shapely.get_parts(geom)), (3, 6))])
        out[p] = geom
    return out


def _assemble(outers: np.ndarray, holes: np.ndarray, rings: np.ndarray, polys: np.ndarray,
              area: np.ndarray, xy: np.ndarray, ring_start: np.ndarray) -> shapely.Geometry:
    """Attach each hole to its smallest containing outline; union overlapping outlines."""
    owner = np.full(len(holes), -1, dtype=np.int64)
    owner_area = np.full(len(holes), np.inf)
    hx = xy[ring_start[holes], 0]
    hy = xy[ring_start[holes], 1]
    for k, o in enumerate(outers):
        if len(holes) == 0:
            break
        inside = shapely.contains_xy(polys[o], hx, hy) if len(holes) else np.zeros(0, bool)
        better = inside & (area[o] < owner_area)
        owner[better] = k
        owner_area[better] = area[o]
    parts = []
    for k, o in enumerate(outers):
        mine = holes[owner == k]
        parts.append(shapely.Polygon(rings[o], [rings[h] for h in mine]) if len(mine) else polys[o])
    if len(parts) == 1:
        return parts[0]
    bounds = shapely.bounds(np.asarray(parts, dtype=object))
    overlap = ((bounds[:, None, 0] < bounds[None, :, 2]) & (bounds[None, :, 0] < bounds[:, None, 2])
               & (bounds[:, None, 1] < bounds[None, :, 3]) & (bounds[None, :, 1] < bounds[:, None, 3]))
    np.fill_diagonal(overlap, False)
    if overlap.any():
        return shapely.union_all(parts)
    return shapely.MultiPolygon(parts)
