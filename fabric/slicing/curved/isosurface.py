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

__all__ = ["Surface", "iso_surface", "clip_surface", "iso_lines", "boundary_loops"]

_TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])


@dataclass(frozen=True)
class Surface:
    """A triangle mesh with per-vertex attributes (columns 0..2: the position, mm)."""

    attrs: np.ndarray       # (n, k)
    tris: np.ndarray        # (m, 3) int64

    @property
    def points(self) -> np.ndarray:
        return self.attrs[:, :3]


def _cut_edges(a: np.ndarray, b: np.ndarray, values: np.ndarray, level: float,
               attrs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weld the crossings of edges (a[i], b[i]): unique vertex index per edge and the new attribute rows."""
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    key = lo.astype(np.int64) * (int(max(attrs.shape[0], 1)) + 1) + hi
    uniq, inverse = np.unique(key, return_inverse=True)
    first = np.zeros(len(uniq), dtype=np.int64)
    first[inverse] = np.arange(len(key))
    ua, ub = lo[first], hi[first]
    va, vb = values[ua], values[ub]
    t = np.clip((level - va) / np.where(vb != va, vb - va, 1.0), 0.0, 1.0)
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
    """Chain segments (k, 2) of vertex ids into polylines: (ids, closed), walking shared ids."""
    if len(segments) == 0:
        return []
    nbrs: dict[int, list[int]] = {}
    for i, (p, q) in enumerate(segments.tolist()):
        nbrs.setdefault(p, []).append(i)
        nbrs.setdefault(q, []).append(i)
    used = np.zeros(len(segments), dtype=bool)
    seg = segments.tolist()
    out: list[tuple[np.ndarray, bool]] = []
    # start open chains at their ends first, then the remaining closed loops anywhere
    starts = [v for v, s in nbrs.items() if len(s) == 1] + list(nbrs)
    for start in starts:
        free = [s for s in nbrs[start] if not used[s]]
        if not free:
            continue
        ids, cur = [start], start
        while True:
            nxt = [s for s in nbrs[cur] if not used[s]]
            if not nxt:
                break
            s = nxt[0]
            used[s] = True
            p, q = seg[s]
            cur = q if p == cur else p
            ids.append(cur)
            if cur == start:
                break
        closed = len(ids) > 3 and ids[0] == ids[-1]
        out.append((np.asarray(ids[:-1] if closed else ids, dtype=np.int64), closed))
    return out


def iso_lines(surface: Surface, values: np.ndarray, level: float) -> list[tuple[np.ndarray, bool]]:
    """Polylines ``values == level`` on a triangle mesh: (attribute rows per point, closed)."""
    if len(surface.tris) == 0:
        return []
    above = values[surface.tris] > level
    count = above.sum(axis=1)
    cut = (count == 1) | (count == 2)
    tt, aa, cc = surface.tris[cut], above[cut], count[cut]
    odd = np.where(cc[:, None] == 1, aa, ~aa)
    shift = np.argmax(odd, axis=1)
    r = np.take_along_axis(tt, (shift[:, None] + np.arange(3)[None, :]) % 3, axis=1)
    if len(r) == 0:
        return []
    a = np.concatenate([r[:, 0], r[:, 0]])
    b = np.concatenate([r[:, 1], r[:, 2]])
    idx, rows = _cut_edges(a, b, values, level, surface.attrs)
    m = len(r)
    segments = np.stack([idx[:m], idx[m:]], axis=1)
    segments = segments[segments[:, 0] != segments[:, 1]]
    return [(rows[ids], closed) for ids, closed in _chain(segments)]


def boundary_loops(surface: Surface) -> list[tuple[np.ndarray, bool]]:
    """The boundary curves of a triangle mesh (edges used by one triangle), as attribute rows."""
    if len(surface.tris) == 0:
        return []
    e = surface.tris[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    key = np.sort(e, axis=1)
    uniq, counts = np.unique(key, axis=0, return_counts=True)
    boundary = uniq[counts == 1]
    return [(surface.attrs[ids], closed) for ids, closed in _chain(boundary)]
