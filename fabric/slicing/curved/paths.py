"""Toolpaths on one curved layer: perimeters offset inward along the surface, then infill lines.

A layer is a triangle mesh (its mid-surface) whose vertices carry the layer's
normal, the nozzle axis and the local layer thickness. Perimeters are level
sets of the distance to the layer's boundary curves (measured in space from
densely sampled boundary points, which on a gently curved layer is the
distance along the surface), one bead spacing apart starting half a spacing
in. Infill is the level sets of a linear coordinate (a family of parallel
vertical planes at the infill angle, turned 90 degrees every layer) on the part
of the layer inside the innermost perimeter. Each path point is raised from
the mid-surface to the top of the layer along the layer normal: that is where
the nozzle tip rides.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from fabric.slicing.curved.axis import unit_rows
from fabric.slicing.curved.isosurface import Surface, boundary_loops, clip_surface, iso_lines_many
from fabric.slicing.flow import bead_spacing_mm
from fabric.slicing.profile import Profile

__all__ = ["CurvedPath", "LayerSpec", "layer_paths", "order_paths", "POS", "NORMAL", "AXIS", "THICK", "CLIP",
           "UNDER_TOP"]

# attribute columns carried by layer surfaces (UNDER_TOP: the distance from a top the band does not lay, mm)
POS, NORMAL, AXIS = slice(0, 3), slice(3, 6), slice(6, 9)
THICK, CLIP, UNDER_TOP, N_ATTRS = 9, 10, 11, 12
MIN_PATH_R = 2.0            # paths shorter than this many bead widths are dropped
MIN_STEP_MM = 0.02          # points closer than this along a path are merged


@dataclass(frozen=True)
class LayerSpec:
    """What kind of layer this is: its index, whether it is solid, its infill angle."""

    index: int
    solid: bool
    infill_angle_deg: float


@dataclass
class CurvedPath:
    """One extruded polyline of a curved layer: nozzle tip positions, axes and bead sizes per point."""

    layer: int
    role: str                  # "perimeter", "solid infill" or "infill"
    points_mm: np.ndarray      # (n, 3) nozzle tip, plate frame
    axes: np.ndarray           # (n, 3) unit nozzle axis, tip towards the nozzle
    normals: np.ndarray        # (n, 3) unit layer normal (the build direction) under each point
    heights_mm: np.ndarray     # (n,) layer thickness under each point
    width_mm: float
    closed: bool

    def length_mm(self) -> float:
        return float(np.linalg.norm(np.diff(self.points_mm, axis=0), axis=1).sum())

    def taken(self, idx: np.ndarray, closed: bool) -> CurvedPath:
        """The path through points ``idx`` (reordered, reversed)."""
        return CurvedPath(self.layer, self.role, self.points_mm[idx], self.axes[idx], self.normals[idx],
                          self.heights_mm[idx], self.width_mm, closed)


def _boundary_distance(surface: Surface, step_mm: float, reach_mm: float) -> np.ndarray:
    """Distance (mm) from each vertex to the layer's boundary, from boundary points ``step_mm`` apart.

    Only distances up to ``reach_mm`` plus the longest edge are exact (farther
    vertices get that bound): the callers cut level sets below ``reach_mm``, and
    an edge crossing one has both ends within that bound.
    """
    loops = boundary_loops(surface)
    if not loops:
        return np.full(len(surface.attrs), np.inf)
    pts = []
    for rows, closed in loops:
        p = rows[:, :3]
        pts.append(np.vstack([p, p[:1]]) if closed else p)
    starts = np.concatenate([p[:-1] for p in pts])
    seg = np.concatenate([np.diff(p, axis=0) for p in pts])
    counts = np.maximum(np.ceil(np.sqrt(np.einsum("ij,ij->i", seg, seg)) / step_mm).astype(np.int64), 1)
    owner = np.repeat(np.arange(len(seg)), counts)
    frac = (np.arange(len(owner)) - np.repeat(np.cumsum(counts) - counts, counts)) / counts[owner]
    samples = np.vstack([starts[owner] + seg[owner] * frac[:, None]] + [p[-1:] for p in pts])
    e = surface.points[surface.tris[:, [0, 1, 2]]] - surface.points[surface.tris[:, [1, 2, 0]]]
    bound = reach_mm + float(np.sqrt(np.einsum("ijk,ijk->ij", e, e).max())) + step_mm
    dist, _ = cKDTree(samples).query(surface.points, distance_upper_bound=bound)
    return np.minimum(np.asarray(dist), bound)


def _to_path(rows: np.ndarray, closed: bool, spec: LayerSpec, role: str, width_mm: float) -> CurvedPath | None:
    """Attribute rows of a polyline -> a path at the top of the layer, or None when too short."""
    step = np.diff(rows[:, :3], axis=0)
    keep = np.ones(len(rows), dtype=bool)
    keep[1:] = np.einsum("ij,ij->i", step, step) > MIN_STEP_MM ** 2
    rows = rows[keep]
    if len(rows) < 2:
        return None
    if closed:
        rows = np.vstack([rows, rows[:1]])
    normal = unit_rows(rows[:, NORMAL])
    thick = rows[:, THICK]
    pts = rows[:, POS] + normal * (thick / 2.0)[:, None]
    d = np.diff(pts, axis=0)
    if float(np.sqrt(np.einsum("ij,ij->i", d, d)).sum()) < MIN_PATH_R * width_mm:
        return None
    return CurvedPath(spec.index, role, pts, unit_rows(rows[:, AXIS]), normal, thick, width_mm, closed)


def layer_paths(surface: Surface, spec: LayerSpec, profile: Profile) -> list[CurvedPath]:
    """Perimeters and infill of one layer's mid-surface, unordered."""
    if len(surface.tris) == 0:
        return []
    width = profile.extrusion_width_mm
    spacing = bead_spacing_mm(width, profile.layer_height_mm)
    inner = max(profile.perimeters - profile.infill_overlap_r, 0.0) * spacing
    dist = _boundary_distance(surface, spacing / 4.0, max(profile.perimeters * spacing, inner))
    with_dist = Surface(np.column_stack([surface.attrs, dist]), surface.tris)
    out: list[CurvedPath] = []
    levels = (np.arange(profile.perimeters) + 0.5) * spacing
    for lines in iso_lines_many(with_dist, dist, levels):
        out += _paths(lines, spec, "perimeter", width)
    region = clip_surface(with_dist, N_ATTRS, inner) if profile.perimeters else with_dist
    if spec.solid:
        return out + _infill(region, spec, "solid infill", spacing, width)
    # sparse, but solid within the top layers under a top the band does not lay (tops.py)
    depth = profile.top_solid_layers * profile.layer_height_mm
    out += _infill(clip_surface(region, UNDER_TOP, depth, keep_above=False), spec, "solid infill", spacing, width)
    if profile.infill_density_r > 0.0:
        out += _infill(clip_surface(region, UNDER_TOP, depth), spec, "infill", spacing / profile.infill_density_r,
                       width)
    return out


def _infill(region: Surface, spec: LayerSpec, role: str, pitch_mm: float, width_mm: float) -> list[CurvedPath]:
    """Infill lines ``pitch_mm`` apart over ``region``, at the layer's infill angle."""
    if len(region.tris) == 0:
        return []
    angle = math.radians(spec.infill_angle_deg)
    coord = region.points[:, 0] * math.cos(angle) + region.points[:, 1] * math.sin(angle)
    first = math.floor(coord.min() / pitch_mm) * pitch_mm + pitch_mm / 2.0
    out: list[CurvedPath] = []
    for lines in iso_lines_many(region, coord, np.arange(first, coord.max(), pitch_mm)):
        out += _paths(lines, spec, role, width_mm)
    return out


def _paths(lines: list[tuple[np.ndarray, bool]], spec: LayerSpec, role: str, width_mm: float) -> list[CurvedPath]:
    paths = (_to_path(rows[:, :N_ATTRS], closed, spec, role, width_mm) for rows, closed in lines)
    return [p for p in paths if p is not None]


def order_paths(paths: list[CurvedPath], start_mm: np.ndarray) -> list[CurvedPath]:
    """Perimeters first, then infill; each next path the one that starts nearest the last end.

    Open paths may be reversed; closed loops are rotated to start at their
    point nearest the nozzle. Every candidate start point (both ends of an
    open path, every point of a loop) is one row of an array, so each pick is
    one vectorised nearest-point search.
    """
    ordered: list[CurvedPath] = []
    here = np.asarray(start_mm, dtype=float)
    for roles in (("perimeter",), ("solid infill", "infill")):
        todo = [p for p in paths if p.role in roles]
        if not todo:
            continue
        starts = [p.points_mm[:-1] if p.closed else p.points_mm[[0, -1]] for p in todo]
        owner = np.repeat(np.arange(len(todo)), [len(s) for s in starts])
        where = np.concatenate([np.arange(len(s)) if p.closed else np.array([0, -1])
                                for p, s in zip(todo, starts, strict=True)])
        pts = np.vstack(starts)
        alive = np.ones(len(pts), dtype=bool)
        first_row = np.r_[0, np.cumsum([len(s) for s in starts])]
        for _ in range(len(todo)):
            d = pts - here
            d2 = np.where(alive, np.einsum("ij,ij->i", d, d), np.inf)
            row = int(np.argmin(d2))
            i, how = int(owner[row]), int(where[row])
            alive[first_row[i]:first_row[i + 1]] = False
            p = todo[i]
            if p.closed and how:
                k = len(p.points_mm) - 1
                idx = np.r_[np.arange(how, k), np.arange(0, how), how]
                p = p.taken(idx, True)
            elif not p.closed and how == -1:
                p = p.taken(np.arange(len(p.points_mm))[::-1], False)
            ordered.append(p)
            here = p.points_mm[-1]
    return ordered
