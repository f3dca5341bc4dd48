"""Level sets on simplicial meshes: iso-surfaces of a tetrahedral field, clipping of a triangle mesh,
iso-lines on a triangle mesh, and boundary loops.

Every function carries an attribute matrix along (one row per vertex: the
position and whatever the caller interpolates: build direction, nozzle axis,
field values), interpolated linearly on the cut edges. New vertices are keyed
by the edge they lie on, so neighbouring elements share them and the results
are connected meshes and continuous polylines, not triangle soup.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

__all__ = ["Surface", "iso_surface", "clip_surface", "iso_lines", "iso_lines_many", "boundary_loops"]

_TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])


@dataclass(frozen=True)
class Surface:
    """A triangle mesh with per-vertex attributes (columns 0..2: the position, mm)."""

    attrs: np.ndarray       # (n, k)
    tris: np.ndarray        # (m, 3) int64

    @property
    def points(self) -> np.ndarray:
        return self.attrs[:, :3]


def _cut_edges(a: np.ndarray, b: np.ndarray, values: np.ndarray, level: float | np.ndarray,
               attrs: np.ndarray, tag: np.ndarray | None = None, n_tags: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Weld the crossings of edges (a[i], b[i]) with ``level`` (one for all, or one per edge, then keyed by
    ``tag`` as well): a unique vertex index per crossing and the new attribute rows."""
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    n = np.int64(max(attrs.shape[0], 1) + 1)
    key = lo.astype(np.int64) * n + hi
    if tag is not None:
        key = key * np.int64(n_tags) + tag
    _uniq, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    ua, ub = lo[first], hi[first]
    va, vb = values[ua], values[ub]
    lvl = level[first] if isinstance(level, np.ndarray) else level
    t = np.clip((lvl - va) / np.where(vb != va, vb - va, 1.0), 0.0, 1.0)
    rows = attrs[ua] + t[:, None] * (attrs[ub] - attrs[ua])
    return inverse.reshape(a.shape), rows


def iso_surface(tets: np.ndarray, values: np.ndarray, level: float, attrs: np.ndarray) -> Surface:
    """The surface ``values == level`` inside a tetrahedral mesh (marching tetrahedra)."""
    above = values[tets] > level
    count = above.sum(axis=1)
    cut = (count > 0) & (count < 4)
    tt, aa, cc = tets[cut], above[cut], count[cut]
    order = np.argsort(~aa, axis=1, kind="stable")             # nodes above first
    o = np.take_along_axis(tt, order, axis=1)
    one, three, two = cc == 1, cc == 3, cc == 2
    ends = [o[one][:, [0, 0, 0]], o[one][:, [1, 2, 3]],
            o[three][:, [3, 3, 3]], o[three][:, [0, 1, 2]]]
    tri_a = np.concatenate([ends[0], ends[2]])
    tri_b = np.concatenate([ends[1], ends[3]])
    q = o[two]
    quad_a, quad_b = q[:, [0, 0, 1, 1]], q[:, [2, 3, 3, 2]]
    n_tri = len(tri_a)
    a = np.concatenate([tri_a.ravel(), quad_a.ravel()])
    b = np.concatenate([tri_b.ravel(), quad_b.ravel()])
    if len(a) == 0:
        return Surface(np.zeros((0, attrs.shape[1])), np.zeros((0, 3), dtype=np.int64))
    idx, rows = _cut_edges(a, b, values, level, attrs)
    tri_idx = idx[: 3 * n_tri].reshape(-1, 3)
    quad_idx = idx[3 * n_tri:].reshape(-1, 4)
    tris = np.concatenate([tri_idx, quad_idx[:, [0, 1, 2]], quad_idx[:, [0, 2, 3]]])
    return Surface(rows, tris.astype(np.int64))


def clip_surface(surface: Surface, column: int, level: float, keep_above: bool = True) -> Surface:
    """The part of ``surface`` where attribute ``column`` is >= ``level`` (or <= with ``keep_above`` False)."""
    if len(surface.tris) == 0:
        return surface
    values = surface.attrs[:, column] if keep_above else -surface.attrs[:, column]
    lvl = level if keep_above else -level
    inside = values[surface.tris] >= lvl
    count = inside.sum(axis=1)
    whole = surface.tris[count == 3]
    part = (count == 1) | (count == 2)
    tt, ii, cc = surface.tris[part], inside[part], count[part]
    # rotate each partial triangle so its odd vertex (the lone inside or lone outside one) comes first
    odd = np.where(cc[:, None] == 1, ii, ~ii)
    shift = np.argmax(odd, axis=1)
    roll = (shift[:, None] + np.arange(3)[None, :]) % 3
    r = np.take_along_axis(tt, roll, axis=1)
    a = np.concatenate([r[:, 0], r[:, 0]])
    b = np.concatenate([r[:, 1], r[:, 2]])
    n_old = len(surface.attrs)
    if len(a):
        idx, rows = _cut_edges(a, b, values, lvl, surface.attrs)
        idx = idx + n_old
    else:
        idx, rows = np.zeros(0, dtype=np.int64), np.zeros((0, surface.attrs.shape[1]))
    m = len(r)
    e01, e02 = idx[:m], idx[m:]
    single = cc == 1
    new_tris = [whole,
                np.stack([r[single, 0], e01[single], e02[single]], axis=1),
                np.stack([e01[~single], r[~single, 1], r[~single, 2]], axis=1),
                np.stack([e01[~single], r[~single, 2], e02[~single]], axis=1)]
    tris = np.concatenate(new_tris).astype(np.int64)
    attrs = np.concatenate([surface.attrs, rows])
    used = np.unique(tris.ravel())
    remap = np.full(len(attrs), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return Surface(attrs[used], remap[tris])


def _chain(segments: np.ndarray) -> list[tuple[np.ndarray, bool]]:
    """Chain segments (k, 2) of vertex ids into polylines: (ids, closed).

    Level sets on a manifold triangle mesh meet at most two segments per
    vertex; those are chained all at once (:func:`_chain_simple`). Where more
    meet (two boundary loops touching at a vertex) the segments are walked one
    by one (:func:`_chain_walk`).
    """
    if len(segments) == 0:
        return []
    degree = np.bincount(segments.ravel())
    return _chain_simple(segments, degree) if degree.max() <= 2 else _chain_walk(segments, degree)


def _chain_simple(segments: np.ndarray, degree: np.ndarray) -> list[tuple[np.ndarray, bool]]:
    """Chains of a graph whose vertices have at most two segments, by pointer jumping.

    Segment i gives two half-edges, ``2i`` (its first vertex to its second) and
    ``2i + 1`` (back). The half-edge after ``u -> v`` is ``v``'s other one, so
    every chain is two orbits of ``next``, one per direction. A loop's orbits
    are cut before their smallest half-edge; then doubling ``next`` gives each
    half-edge its orbit's last half-edge and its distance to it, in log2(longest
    chain) vectorised steps. One direction of every chain is kept (the one whose
    smallest, for a loop, or last, for a line, half-edge is below the other's),
    and its half-edges in order give the vertices.
    """
    k = len(segments)
    tail = segments.ravel()                                 # half-edge h runs tail[h] -> tail[h ^ 1]
    head = tail.reshape(-1, 2)[:, ::-1].ravel()
    half = np.arange(2 * k)
    out_of = np.argsort(tail, kind="stable")                # the half-edges leaving each vertex, grouped
    first = np.searchsorted(tail[out_of], np.arange(len(degree) + 1))
    a = out_of[first[head]]                                 # the (one or two) half-edges leaving the head
    b = np.where(degree[head] == 2, out_of[np.minimum(first[head] + 1, 2 * k - 1)], -1)
    nxt = np.where(a != (half ^ 1), a, b)
    nxt = np.where(nxt == (half ^ 1), -1, nxt)
    # loops: every vertex has two segments; their orbits never end. Cut each before its smallest half-edge.
    n = len(degree)
    _count, label = csgraph.connected_components(sp.csr_matrix((np.ones(k), (segments[:, 0], segments[:, 1])),
                                                               shape=(n, n)), directed=False)
    rounds = max(int(np.ceil(np.log2(2 * np.bincount(label).max() + 1))), 1)
    smallest, jump = half.copy(), np.where(nxt >= 0, nxt, half)
    for _ in range(rounds):
        smallest = np.minimum(smallest, smallest[jump])
        jump = jump[jump]
    in_loop = nxt[jump] >= 0                                # a line's orbit ends up at its last half-edge
    cut = in_loop & (nxt >= 0) & (nxt == smallest)
    nxt = np.where(cut, -1, nxt)
    # distance to the orbit's end and its last half-edge
    last, dist = np.where(nxt >= 0, nxt, half), (nxt >= 0).astype(np.int64)
    for _ in range(rounds):
        dist = dist + dist[last]
        last = last[last]
    keep = np.where(in_loop, smallest < smallest[half ^ 1], last < last[half ^ 1])
    kept = half[keep]
    order = kept[np.lexsort((-dist[kept], last[kept]))]
    bounds = np.flatnonzero(np.diff(last[order])) + 1
    out: list[tuple[np.ndarray, bool]] = []
    for run in np.split(order, bounds):
        closed = bool(in_loop[run[0]]) and len(run) >= 3
        ids = tail[run] if closed else np.concatenate((tail[run], head[run[-1:]]))
        out.append((ids, closed))
    return out


def _chain_walk(segments: np.ndarray, degree: np.ndarray) -> list[tuple[np.ndarray, bool]]:
    """Chains of any graph: open chains from their ends (odd degree) first, then loops anywhere; a vertex
    with more segments is walked through as often as it has them."""
    flat = segments.ravel()
    slots = np.argsort(flat, kind="stable")
    ptr = np.searchsorted(flat[slots], np.arange(len(degree) + 1)).tolist()
    seg_of = (slots // 2).tolist()
    other = flat[slots ^ 1].tolist()
    used = bytearray(len(segments))
    out: list[tuple[np.ndarray, bool]] = []
    for start in np.flatnonzero(degree % 2 == 1).tolist() + np.flatnonzero(degree > 0).tolist():
        ids, cur = [start], start
        while True:
            j, stop = ptr[cur], ptr[cur + 1]
            while j < stop and used[seg_of[j]]:
                j += 1
            if j == stop:
                break
            used[seg_of[j]] = 1
            cur = other[j]
            ids.append(cur)
            if cur == start:
                break
        if len(ids) < 2:
            continue
        closed = len(ids) > 3 and ids[0] == ids[-1]
        out.append((np.asarray(ids[:-1] if closed else ids, dtype=np.int64), closed))
    return out


def iso_lines(surface: Surface, values: np.ndarray, level: float) -> list[tuple[np.ndarray, bool]]:
    """Polylines ``values == level`` on a triangle mesh: (attribute rows per point, closed)."""
    return iso_lines_many(surface, values, np.array([level]))[0]


def iso_lines_many(surface: Surface, values: np.ndarray, levels: np.ndarray) -> list[list[tuple[np.ndarray, bool]]]:
    """The polylines of every level of ``levels`` (ascending) at once, one list per level.

    Each triangle is paired with the levels that cross it (``min <= level <
    max`` over its corners, as ``values > level`` splits them), so the work is
    proportional to the crossings, not to triangles times levels. Crossings
    are welded per (edge, level), and all levels are chained in one walk.
    """
    out: list[list[tuple[np.ndarray, bool]]] = [[] for _ in range(len(levels))]
    if len(surface.tris) == 0 or len(levels) == 0:
        return out
    vals = values[surface.tris]
    k_lo = np.searchsorted(levels, vals.min(axis=1), side="left")
    k_hi = np.searchsorted(levels, vals.max(axis=1), side="left")
    count = np.maximum(k_hi - k_lo, 0)
    owner = np.repeat(np.arange(len(surface.tris)), count)
    if len(owner) == 0:
        return out
    k = k_lo[owner] + np.arange(len(owner)) - np.repeat(np.cumsum(count) - count, count)
    level = levels[k]
    tt = surface.tris[owner]
    above = vals[owner] > level[:, None]
    odd = np.where(above.sum(axis=1)[:, None] == 1, above, ~above)        # the lone vertex on its side
    shift = np.argmax(odd, axis=1)
    r = np.take_along_axis(tt, (shift[:, None] + np.arange(3)[None, :]) % 3, axis=1)
    a = np.concatenate([r[:, 0], r[:, 0]])
    b = np.concatenate([r[:, 1], r[:, 2]])
    idx, rows = _cut_edges(a, b, values, np.concatenate([level, level]), surface.attrs,
                           np.concatenate([k, k]), len(levels))
    m = len(r)
    segments = np.stack([idx[:m], idx[m:]], axis=1)
    segments = segments[segments[:, 0] != segments[:, 1]]
    vertex_level = np.zeros(len(rows), dtype=np.int64)
    vertex_level[idx] = np.concatenate([k, k])
    for ids, closed in _chain(segments):
        out[int(vertex_level[ids[0]])].append((rows[ids], closed))
    return out


def boundary_loops(surface: Surface) -> list[tuple[np.ndarray, bool]]:
    """The boundary curves of a triangle mesh (edges used by one triangle), as attribute rows."""
    if len(surface.tris) == 0:
        return []
    e = np.sort(surface.tris[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    n = np.int64(len(surface.attrs))
    uniq, counts = np.unique(e[:, 0] * n + e[:, 1], return_counts=True)
    key = uniq[counts == 1]
    boundary = np.column_stack([key // n, key % n])
    return [(surface.attrs[ids], closed) for ids, closed in _chain(boundary)]
