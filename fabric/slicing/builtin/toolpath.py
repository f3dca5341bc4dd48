"""Seams and print order: where each loop starts and in which order islands and loops are visited.

A loop starts at its *seam* vertex. ``aligned`` scores every vertex by how
far it lies towards the rear right of the bed (its projection on the
``(1, 1)`` diagonal), ``nearest`` by how close it is to the nozzle; both add
a bonus for a *concave* corner, where the seam's blob hides in the notch
(material lies left of a loop's direction, outlines counter-clockwise and
holes clockwise, so a right turn is a notch; the bonus grows with the turn
up to 60 degrees). On a prismatic part the same vertex wins on every layer,
so an aligned seam runs straight up an inner corner. A loop is printed from
its seam all the way round, less ``0.15 * nozzle`` at the end so the bead
does not pile up where it meets its own start (PrusaSlicer's clipping).

Islands are visited in an order that shortens the jumps between them:
nearest-neighbour from the nozzle over each island's entry point (the seam
of its first loop), then improved by 2-opt moves. Inside an island each
boundary (the outline, every hole) is printed from its innermost loop out to
its external one (the outer surface is laid against an already stable
wall), boundaries nearest-first; then the gap fill and the infill.
"""
from __future__ import annotations

import math

import numpy as np

from fabric.slicing.builtin.gapfill import GapPath
from fabric.slicing.builtin.regions import Island, Loop

__all__ = ["loop_path", "seam_point", "order_loops", "order_islands", "order_gaps", "LOOP_CLIP_R",
           "SEAM_CORNER_BONUS_MM"]

LOOP_CLIP_R = 0.15
SEAM_CORNER_BONUS_MM = {"aligned": 5.0, "nearest": 2.0}   # score bonus of a full (>= 60 deg) notch
_NOTCH_FULL_RAD = math.pi / 3.0
_REAR = np.array([1.0, 1.0]) / math.sqrt(2.0)


def seam_point(loop: Loop, policy: str, nozzle_xy: tuple[float, float]) -> tuple[float, float]:
    """The vertex where ``loop`` starts under ``policy`` (``aligned`` or ``nearest``), notches preferred."""
    xy = loop.xy
    if policy == "aligned":
        score = xy @ _REAR
    else:
        score = -np.hypot(xy[:, 0] - nozzle_xy[0], xy[:, 1] - nozzle_xy[1])
    if len(xy) >= 3:
        if loop.notch is None:                 # loops are shared by equal layers: weigh the corners once
            before = xy - np.roll(xy, 1, axis=0)
            after = np.roll(xy, -1, axis=0) - xy
            turn = np.arctan2(before[:, 0] * after[:, 1] - before[:, 1] * after[:, 0],
                              (before * after).sum(axis=1))           # > 0 left, < 0 right (a notch)
            loop.notch = np.clip(-turn / _NOTCH_FULL_RAD, 0.0, 1.0)
        score = score + SEAM_CORNER_BONUS_MM.get(policy, 0.0) * loop.notch
    best = int(np.argmax(score))
    return float(xy[best, 0]), float(xy[best, 1])


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


def order_loops(island: Island, start_xy: tuple[float, float] | None = None) -> list[Loop]:
    """Loops boundary by boundary, each from its deepest loop out to its external one.

    Every external loop (depth 0: the outline, or a hole's edge) heads a
    family; a deeper loop joins the family of the external loop of the same
    kind (outline or hole) nearest to it. Families are visited nearest-first
    from ``start_xy``, so the nozzle finishes one boundary before it moves to
    the next, instead of crossing the part once for the inner and once more for
    the external loops.
    """
    loops = island.loops
    heads = [lp for lp in loops if lp.depth == 0]
    if start_xy is None or not all(math.isfinite(v) for v in start_xy) or len(heads) <= 1:
        return sorted(loops, key=lambda lp: -lp.depth)
    family: dict[int, list[Loop]] = {k: [] for k in range(len(heads))}
    for lp in loops:
        same = [k for k, h in enumerate(heads) if h.hole == lp.hole] or list(range(len(heads)))
        k = min(same, key=lambda k: float(((heads[k].xy - lp.xy[0]) ** 2).sum(axis=1).min()))
        family[k].append(lp)
    out: list[Loop] = []
    pos = np.asarray(start_xy, dtype=np.float64)
    todo = [sorted(members, key=lambda lp: -lp.depth) for members in family.values() if members]
    while todo:
        best = min(range(len(todo)), key=lambda k: float(((todo[k][0].xy - pos) ** 2).sum(axis=1).min()))
        members = todo.pop(best)
        out += members
        last = members[-1].xy
        pos = last[int(np.argmin(((last - pos) ** 2).sum(axis=1)))]
    return out


def order_islands(islands: list[Island], start_xy: tuple[float, float], seam: str = "aligned") -> list[Island]:
    """Nearest-neighbour order of the islands' entry points from ``start_xy``, improved by 2-opt."""
    if len(islands) <= 1:
        return list(islands)
    entry = np.asarray([seam_point(_first_loop(isl), seam, start_xy) for isl in islands])
    n = len(islands)
    pos = np.asarray(start_xy, dtype=np.float64)
    remaining = list(range(n))
    tour: list[int] = []
    while remaining:
        best = min(remaining, key=lambda i: float(((entry[i] - pos) ** 2).sum()))
        remaining.remove(best)
        tour.append(best)
        pos = entry[best]
    pts = np.vstack([np.asarray(start_xy, dtype=np.float64)[None], entry])    # node 0: the start

    def d(i: int, j: int) -> float:
        return float(np.hypot(*(pts[i] - pts[j])))

    # 2-opt on the open path start -> tour (reversing a stretch when that shortens it)
    path = [0] + [t + 1 for t in tour]
    improved = True
    rounds = 0
    while improved and rounds < 20:
        improved = False
        rounds += 1
        for i in range(1, len(path) - 1):
            for j in range(i + 1, len(path)):
                a, b = path[i - 1], path[i]
                c = path[j]
                nxt = path[j + 1] if j + 1 < len(path) else None
                old = d(a, b) + (d(c, nxt) if nxt is not None else 0.0)
                new = d(a, c) + (d(b, nxt) if nxt is not None else 0.0)
                if new < old - 1e-9:
                    path[i:j + 1] = path[i:j + 1][::-1]
                    improved = True
    return [islands[k - 1] for k in path[1:]]


def order_gaps(gaps: list[GapPath], start_xy: tuple[float, float]) -> list[GapPath]:
    """Gap-fill beads nearest-first from ``start_xy``, each entered at its nearer end (reversed if need be)."""
    if len(gaps) <= 1 or not all(math.isfinite(v) for v in start_xy):
        return list(gaps)
    ends = np.asarray([[g.xy[0], g.xy[-1]] for g in gaps])          # (n, 2, 2)
    todo = np.ones(len(gaps), dtype=bool)
    pos = np.asarray(start_xy, dtype=np.float64)
    out = []
    while todo.any():
        d = np.where(todo[:, None], np.hypot(ends[:, :, 0] - pos[0], ends[:, :, 1] - pos[1]), np.inf)
        k, end = np.unravel_index(int(np.argmin(d)), d.shape)
        todo[k] = False
        g = gaps[k]
        out.append(g if end == 0 else GapPath(g.xy[::-1], g.widths_mm[::-1]))
        pos = ends[k, 1 - end]
    return out


def _first_loop(island: Island) -> Loop:
    """The loop an island starts with (its deepest), or its outline when it has none."""
    if island.loops:
        return max(island.loops, key=lambda lp: lp.depth)
    coords = np.asarray(island.outline.exterior.coords)[:-1] if hasattr(island.outline, "exterior") \
        else np.zeros((1, 2))
    return Loop(coords[:, :2], 0, False)
