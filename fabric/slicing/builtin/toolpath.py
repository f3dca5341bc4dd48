"""Seams and print order: where each loop starts and in which order islands are visited.

A loop starts at its *seam* vertex. ``aligned`` picks, on every layer, the
vertex nearest a fixed point behind and to the right of the part (the seam
then runs up one edge, where it shows least and is predictable); ``nearest``
picks the vertex nearest the nozzle, which shortens travel. A loop is printed
from its seam all the way round, less ``0.15 * nozzle`` at the end so the
bead does not pile up where it meets its own start (PrusaSlicer's clipping).

Islands are visited nearest-first from the nozzle's position; inside one,
inner perimeters come first and the external one last (the outer surface is
laid against an already stable wall), then the infill.
"""
from __future__ import annotations

import numpy as np

from fabric.slicing.builtin.regions import Island, Loop

__all__ = ["loop_path", "order_loops", "order_islands", "LOOP_CLIP_R"]

LOOP_CLIP_R = 0.15


def loop_path(loop: Loop, seam_xy: tuple[float, float], clip_mm: float) -> np.ndarray:
    """The loop as an open polyline from the vertex nearest ``seam_xy`` round to (almost) itself."""
    xy = loop.xy
    start = int(np.argmin((xy[:, 0] - seam_xy[0]) ** 2 + (xy[:, 1] - seam_xy[1]) ** 2))
    path = np.vstack([xy[start:], xy[:start + 1]])
    if clip_mm <= 0:
        return path
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    total = float(seg.sum())
    if total <= 2 * clip_mm:
        return path
    # walk back from the end by clip_mm
    cum = np.cumsum(seg[::-1])
    j = int(np.searchsorted(cum, clip_mm))           # segment (from the end) holding the cut
    before = cum[j - 1] if j else 0.0
    t = (clip_mm - before) / seg[::-1][j]
    end_idx = len(path) - 1 - j                      # cut lies on segment (end_idx - 1, end_idx)
    cut = path[end_idx] + t * (path[end_idx - 1] - path[end_idx])
    return np.vstack([path[:end_idx], cut[None]])


def order_loops(island: Island) -> list[Loop]:
    """Deepest loops first, the external perimeter(s) last."""
    return sorted(island.loops, key=lambda lp: -lp.depth)


def order_islands(islands: list[Island], start_xy: tuple[float, float]) -> list[Island]:
    """Greedy nearest-neighbour order of islands by their outline's nearest vertex."""
    if len(islands) <= 1:
        return list(islands)
    remaining = list(range(len(islands)))
    pts = [np.asarray(lp.xy) for lp in (_first_loop(i) for i in islands)]
    out = []
    pos = np.asarray(start_xy, dtype=np.float64)
    while remaining:
        best = min(remaining, key=lambda i: float(((pts[i] - pos) ** 2).sum(axis=1).min()))
        remaining.remove(best)
        out.append(islands[best])
        far = pts[best]
        pos = far[int(np.argmin(((far - pos) ** 2).sum(axis=1)))]
    return out


def _first_loop(island: Island) -> Loop:
    if island.loops:
        return island.loops[0]
    coords = np.asarray(island.outline.exterior.coords)[:-1] if hasattr(island.outline, "exterior") \
        else np.zeros((1, 2))
    return Loop(coords[:, :2], 0, False)
