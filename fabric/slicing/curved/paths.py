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

from fabric.slicing.curved.isosurface import Surface, boundary_loops, clip_surface, iso_lines
from fabric.slicing.flow import bead_spacing_mm
from fabric.slicing.profile import Profile

__all__ = ["CurvedPath", "LayerSpec", "layer_paths", "order_paths", "POS", "NORMAL", "AXIS", "THICK", "CLIP"]

# attribute columns carried by layer surfaces
POS, NORMAL, AXIS = slice(0, 3), slice(3, 6), slice(6, 9)
THICK, CLIP, N_ATTRS = 9, 10, 11
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
    heights_mm: np.ndarray     # (n,) layer thickness under each point
    width_mm: float
    closed: bool

    def length_mm(self) -> float:
        return float(np.linalg.norm(np.diff(self.points_mm, axis=0), axis=1).sum())


def _boundary_distance(surface: Surface, step_mm: float) -> np.ndarray:
    """Distance (mm) from each vertex to the layer's boundary, from boundary points ``step_mm`` apart."""
    samples = []
    for rows, closed in boundary_loops(surface):
        pts = rows[:, :3]
        if closed:
            pts = np.vstack([pts, pts[:1]])
        seg = np.diff(pts, axis=0)
        counts = np.maximum(np.ceil(np.linalg.norm(seg, axis=1) / step_mm).astype(np.int64), 1)
        owner = np.repeat(np.arange(len(seg)), counts)
        frac = (np.arange(len(owner)) - np.repeat(np.cumsum(counts) - counts, counts)) / counts[owner]
        samples.append(pts[:-1][owner] + seg[owner] * frac[:, None])
        samples.append(pts[-1:])
    if not samples:
        return np.full(len(surface.attrs), np.inf)
    tree = cKDTree(np.vstack(samples))
    dist, _ = tree.query(surface.points)
    return np.asarray(dist)


def _to_path(rows: np.ndarray, closed: bool, spec: LayerSpec, role: str, width_mm: float) -> CurvedPath | None:
    """Attribute rows of a polyline -> a path at the top of the layer, or None when too short."""
    keep = np.ones(len(rows), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(rows[:, :3], axis=0), axis=1) > MIN_STEP_MM
    rows = rows[keep]
    if len(rows) < 2:
        return None
    normal = rows[:, NORMAL] / np.maximum(np.linalg.norm(rows[:, NORMAL], axis=1, keepdims=True), 1e-12)
    axes = rows[:, AXIS] / np.maximum(np.linalg.norm(rows[:, AXIS], axis=1, keepdims=True), 1e-12)
    thick = rows[:, THICK]
    pts = rows[:, POS] + normal * (thick / 2.0)[:, None]
    if closed:
        pts, axes, thick = np.vstack([pts, pts[:1]]), np.vstack([axes, axes[:1]]), np.r_[thick, thick[:1]]
    path = CurvedPath(spec.index, role, pts, axes, thick, width_mm, closed)
    return path if path.length_mm() >= MIN_PATH_R * width_mm else None


def layer_paths(surface: Surface, spec: LayerSpec, profile: Profile) -> list[CurvedPath]:
    """Perimeters and infill of one layer's mid-surface, unordered."""
    if len(surface.tris) == 0:
        return []
    width = profile.extrusion_width_mm
    spacing = bead_spacing_mm(width, profile.layer_height_mm)
    dist = _boundary_distance(surface, spacing / 4.0)
    with_dist = Surface(np.column_stack([surface.attrs, dist]), surface.tris)
    out: list[CurvedPath] = []
    for i in range(profile.perimeters):
        for rows, closed in iso_lines(with_dist, dist, (i + 0.5) * spacing):
            path = _to_path(rows[:, :N_ATTRS], closed, spec, "perimeter", width)
            if path is not None:
                out.append(path)
    density = 1.0 if spec.solid else profile.infill_density_r
    if density <= 0.0:
        return out
    inner = max(profile.perimeters - profile.infill_overlap_r, 0.0) * spacing
    region = clip_surface(with_dist, N_ATTRS, inner) if profile.perimeters else with_dist
    if len(region.tris) == 0:
        return out
    angle = math.radians(spec.infill_angle_deg)
    coord = region.points[:, 0] * math.cos(angle) + region.points[:, 1] * math.sin(angle)
    pitch = spacing / density
    first = math.floor(coord.min() / pitch) * pitch + pitch / 2.0
    role = "solid infill" if spec.solid else "infill"
    for level in np.arange(first, coord.max(), pitch):
        for rows, closed in iso_lines(region, coord, float(level)):
            path = _to_path(rows[:, :N_ATTRS], closed, spec, role, width)
            if path is not None:
                out.append(path)
    return out


def order_paths(paths: list[CurvedPath], start_mm: np.ndarray) -> list[CurvedPath]:
    """Perimeters first, then infill; each next path the one that starts nearest the last end.

    Open paths may be reversed; closed loops are rotated to start at their
    point nearest the nozzle.
    """
    ordered: list[CurvedPath] = []
    here = np.asarray(start_mm, dtype=float)
    for roles in (("perimeter",), ("solid infill", "infill")):
        todo = [p for p in paths if p.role in roles]
        while todo:
            best, best_d, how = 0, math.inf, 0
            for i, p in enumerate(todo):
                if p.closed:
                    d = np.linalg.norm(p.points_mm[:-1] - here, axis=1)
                    j = int(np.argmin(d))
                    if d[j] < best_d:
                        best, best_d, how = i, float(d[j]), j
                else:
                    for j, end in ((0, p.points_mm[0]), (-1, p.points_mm[-1])):
                        d0 = float(np.linalg.norm(end - here))
                        if d0 < best_d:
                            best, best_d, how = i, d0, j
            p = todo.pop(best)
            if p.closed and how:
                k = len(p.points_mm) - 1
                idx = np.r_[np.arange(how, k), np.arange(0, how), how]
                p = CurvedPath(p.layer, p.role, p.points_mm[idx], p.axes[idx], p.heights_mm[idx], p.width_mm, True)
            elif not p.closed and how == -1:
                p = CurvedPath(p.layer, p.role, p.points_mm[::-1], p.axes[::-1], p.heights_mm[::-1], p.width_mm,
                               False)
            ordered.append(p)
            here = p.points_mm[-1]
    return ordered
