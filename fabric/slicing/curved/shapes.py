"""Generated test parts for curved slicing: a dome, an inverted frustum, an arch and a wing.

Each is a watertight, outward-wound :class:`trimesh.Trimesh` in mm resting
on z = 0 and centred on the origin in XY; the slicer places it on the plate
as any other model. They exercise what curved layers are for: a top surface
to follow (dome, wing), walls overhanging more than 45 degrees (frustum), an
unsupported span (arch).
"""
from __future__ import annotations

import math

import numpy as np
import trimesh
from shapely.geometry import Polygon

__all__ = ["dome", "inverted_frustum", "arch", "wing", "extrude_xz", "SHAPES"]


def _revolve(profile_rz: list[tuple[float, float]], sections: int) -> trimesh.Trimesh:
    """A solid of revolution about z from a profile (r, z) running from the axis at the bottom to the axis at
    the top, counter-clockwise in the (r, z) half-plane."""
    mesh = trimesh.creation.revolve(np.asarray(profile_rz, dtype=float), sections=sections)
    mesh.merge_vertices()
    trimesh.repair.fix_normals(mesh)
    return mesh


def dome(radius_mm: float = 20.0, height_mm: float = 12.0, rings: int = 24, sections: int = 64) -> trimesh.Trimesh:
    """A spherical cap of base radius ``radius_mm`` and height ``height_mm`` on its flat base."""
    sphere_r = (radius_mm ** 2 + height_mm ** 2) / (2.0 * height_mm)
    rim = math.asin(radius_mm / sphere_r)
    angles = np.linspace(rim, 0.0, rings + 1)
    cap = [(sphere_r * math.sin(a), height_mm - sphere_r + sphere_r * math.cos(a)) for a in angles]
    cap[-1] = (0.0, height_mm)
    return _revolve([(0.0, 0.0), *cap], sections)


def inverted_frustum(bottom_radius_mm: float = 6.0, height_mm: float = 10.0, wall_deg: float = 55.0,
                     sections: int = 64) -> trimesh.Trimesh:
    """A cone frustum standing on its small end; its walls lean out ``wall_deg`` from vertical."""
    top_r = bottom_radius_mm + height_mm * math.tan(math.radians(wall_deg))
    return _revolve([(0.0, 0.0), (bottom_radius_mm, 0.0), (top_r, height_mm), (0.0, height_mm)], sections)


def arch(inner_radius_mm: float = 14.0, outer_radius_mm: float = 20.0, depth_mm: float = 8.0,
         segments: int = 48) -> trimesh.Trimesh:
    """A semicircular arch standing on its two feet, its span along x and its depth along y."""
    t = np.linspace(0.0, math.pi, segments + 1)
    outer = np.column_stack([outer_radius_mm * np.cos(t), outer_radius_mm * np.sin(t)])
    inner = np.column_stack([inner_radius_mm * np.cos(t[::-1]), inner_radius_mm * np.sin(t[::-1])])
    return extrude_xz(Polygon(np.vstack([outer, inner])), depth_mm)


def wing(chord_mm: float = 50.0, span_mm: float = 40.0, thickness_r: float = 0.14,
         stations: int = 40) -> trimesh.Trimesh:
    """A wing section lying flat: a flat-bottomed airfoil (NACA four-digit thickness on top) extruded along y."""
    xi = (1.0 - np.cos(np.linspace(0.0, math.pi, stations + 1))) / 2.0       # denser at the nose
    half = 5.0 * thickness_r * (0.2969 * np.sqrt(xi) - 0.1260 * xi - 0.3516 * xi ** 2 + 0.2843 * xi ** 3
                                - 0.1015 * xi ** 4)
    top = np.column_stack([chord_mm * xi[::-1], 2.0 * chord_mm * half[::-1]])
    top[0, 1] = max(top[0, 1], 0.4)                                         # a printable trailing edge
    outline = np.vstack([[chord_mm, 0.0], top[:-1], [0.0, 0.0]])
    outline = outline[np.r_[True, np.linalg.norm(np.diff(outline, axis=0), axis=1) > 1e-9]]
    return extrude_xz(Polygon(outline).buffer(0), span_mm)


def extrude_xz(polygon: Polygon, depth_mm: float) -> trimesh.Trimesh:
    """Extrude a polygon drawn in the (x, z) plane along y, centred, resting on z = 0."""
    mesh = trimesh.creation.extrude_polygon(polygon, depth_mm)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2.0, [1.0, 0.0, 0.0]))
    lo, hi = mesh.bounds
    mesh.apply_translation([-(lo[0] + hi[0]) / 2.0, -(lo[1] + hi[1]) / 2.0, -lo[2]])
    return mesh


SHAPES = {"dome": dome, "frustum": inverted_frustum, "arch": arch, "wing": wing}
