"""Generated test parts for curved slicing: a dome, an inverted frustum, an arch and a wing; and three the
slicer was not tuned on, a hook, a vase with a flared lip and a bridge with a skewed span.

Each is a watertight, outward-wound :class:`trimesh.Trimesh` in mm resting
on z = 0 and centred on the origin in XY; the slicer places it on the plate
as any other model. They exercise what curved layers are for: a top surface
to follow (dome, wing), walls overhanging more than 45 degrees (frustum), an
unsupported span (arch). The others (:data:`OTHER_SHAPES`) go where the
first four do not: a curl that leans its layers past horizontal, away from
the robot (hook), a cup whose floor and rim are tops the band must not
follow and a lip flaring out 50 degrees (flared vase), a span at an angle
to its piers and to the robot (skewed bridge).
"""
from __future__ import annotations

import math

import numpy as np
import trimesh
from shapely.geometry import Polygon

__all__ = ["dome", "inverted_frustum", "arch", "wing", "hook", "flared_vase", "skewed_bridge", "extrude_xz", "SHAPES",
           "OTHER_SHAPES"]


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


def hook(width_mm: float = 6.0, post_mm: float = 14.0, bend_radius_mm: float = 9.0, sweep_deg: float = 150.0,
         depth_mm: float = 8.0, segments: int = 40) -> trimesh.Trimesh:
    """A J hook: a post ``width_mm`` wide standing ``post_mm`` on the plate, then bending over towards +x round
    a centre ``bend_radius_mm`` out, through ``sweep_deg`` (150: its end points down and out)."""
    t = np.radians(np.linspace(180.0, 180.0 - sweep_deg, segments + 1))
    outer_r, inner_r = bend_radius_mm + width_mm / 2.0, bend_radius_mm - width_mm / 2.0
    outer = np.column_stack([bend_radius_mm + outer_r * np.cos(t), post_mm + outer_r * np.sin(t)])
    inner = np.column_stack([bend_radius_mm + inner_r * np.cos(t[::-1]), post_mm + inner_r * np.sin(t[::-1])])
    foot = np.array([[width_mm / 2.0, 0.0], [-width_mm / 2.0, 0.0]])
    return extrude_xz(Polygon(np.vstack([foot, outer, inner])).buffer(0), depth_mm)


def flared_vase(base_radius_mm: float = 9.0, waist_radius_mm: float = 8.0, lip_radius_mm: float = 17.0,
                body_mm: float = 18.0, lip_mm: float = 7.0, wall_mm: float = 2.0, floor_mm: float = 2.0,
                sections: int = 64) -> trimesh.Trimesh:
    """A cup on a ``floor_mm`` floor whose wall narrows to a waist at ``body_mm`` and then flares out to a lip
    of ``lip_radius_mm`` (about 50 degrees from vertical), its wall ``wall_mm`` thick."""
    lip_inner = lip_radius_mm - 1.2 * wall_mm            # the lip's wall, measured across it, near wall_mm
    return _revolve([(0.0, 0.0), (base_radius_mm, 0.0), (waist_radius_mm, body_mm),
                     (lip_radius_mm, body_mm + lip_mm), (lip_inner, body_mm + lip_mm),
                     (waist_radius_mm - wall_mm, body_mm + 0.5), (base_radius_mm - wall_mm, floor_mm),
                     (0.0, floor_mm)], sections)


def skewed_bridge(span_mm: float = 36.0, pier_mm: float = 6.0, deck_mm: float = 4.0, height_mm: float = 16.0,
                  depth_mm: float = 10.0, skew_deg: float = 30.0, turn_deg: float = 35.0, segments: int = 40
                  ) -> trimesh.Trimesh:
    """A bridge: two piers ``pier_mm`` thick and a ``deck_mm`` deck over a half-elliptic opening, its span
    skewed ``skew_deg`` against its depth (x += tan(skew) y) and turned ``turn_deg`` about z on the plate."""
    half, a, b = span_mm / 2.0, span_mm / 2.0 - pier_mm, height_mm - deck_mm
    t = np.linspace(0.0, math.pi, segments + 1)
    opening = np.column_stack([-a * np.cos(t), b * np.sin(t)])          # from (-a, 0) over the top to (a, 0)
    outline = np.vstack([[[-half, 0.0]], opening, [[half, 0.0], [half, height_mm], [-half, height_mm]]])
    mesh = extrude_xz(Polygon(outline).buffer(0), depth_mm)
    shear = np.eye(4)
    shear[0, 1] = math.tan(math.radians(skew_deg))
    mesh.apply_transform(shear)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(math.radians(turn_deg), [0.0, 0.0, 1.0]))
    lo, hi = mesh.bounds
    mesh.apply_translation([-(lo[0] + hi[0]) / 2.0, -(lo[1] + hi[1]) / 2.0, -lo[2]])
    return mesh


SHAPES = {"dome": dome, "frustum": inverted_frustum, "arch": arch, "wing": wing}
OTHER_SHAPES = {"hook": hook, "flared_vase": flared_vase, "skewed_bridge": skewed_bridge}
