"""Measured figures of a curved slice beside planar slicing of the same part.

* Overhang (the 45 degree rule): a boundary face overhangs when ``n . d <
  -sin 45``, ``n`` its outward normal and ``d`` the local build direction (the
  field's gradient for curved layers, +z for planar ones). Faces lying on the
  plate are supported by it and never count.
* Cusp (staircase) error of the top surface, i.e. the faces that look up
  (``n_z > 0``, off the plate): where layers of thickness ``t`` cut a surface at
  an angle, the step's corner stands ``t |n . d|`` off the surface (a step of
  height ``t`` under a slope of angle ``b`` sticks out ``t cos b``). A face that
  *is* a layer's surface has none: a flat face for planar layers, a face of the
  followed top surface for curved ones. Reported as the area-weighted mean and
  the maximum over the top faces.
* Layer thickness min/max, maximum tilt of the nozzle axis from +z, and the
  largest angle between neighbouring nozzle axes: between consecutive points of
  a path, and between the two ends of every edge of the volume mesh (which
  covers neighbours across layers).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from fabric.slicing.curved.field import BASE_TOL_MM, LayerField
from fabric.slicing.curved.paths import CurvedPath
from fabric.slicing.curved.tetmesh import TetMesh

__all__ = ["CurvedReport", "SurfaceFaces", "surface_faces", "overhang_area_mm2", "cusp_error_mm", "measure"]

SIN45 = math.sin(math.radians(45.0))
FLAT_R = 0.999            # |n_z| above this: a horizontal face


@dataclass(frozen=True)
class CurvedReport:
    """Curved slice figures beside planar slicing of the same part (mm, mm^2, deg, s)."""

    layers: int
    planar_layers: int
    overhang_mm2: float
    planar_overhang_mm2: float
    overhang_reduction_r: float          # 1 - curved / planar (1 when planar has none either)
    thickness_min_mm: float
    thickness_max_mm: float
    thickness_ratio_r: float
    max_tilt_deg: float
    max_neighbour_deg: float             # along the paths
    max_field_neighbour_deg: float       # across the volume mesh's edges
    cusp_mean_mm: float
    planar_cusp_mean_mm: float
    cusp_max_mm: float
    planar_cusp_max_mm: float
    tet_nodes: int
    tets: int
    elapsed_s: float = 0.0

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)

    def header_lines(self) -> list[str]:
        """The figures as G-code comment lines (without ``; ``)."""
        return [f"curved: {k} = {v:.6g}" for k, v in self.as_dict().items() if k != "elapsed_s"]


@dataclass(frozen=True)
class SurfaceFaces:
    """The part's surface as the volume mesh has it (finer than the input where TetGen split it)."""

    normals: np.ndarray        # (f, 3) outward unit
    areas_mm2: np.ndarray      # (f,)
    off_plate: np.ndarray      # (f,) bool: not lying on the plate
    faces: np.ndarray          # (f, 3) node indices


def surface_faces(mesh: TetMesh) -> SurfaceFaces:
    """The boundary triangles of ``mesh`` with their normals, areas and whether they lie on the plate."""
    faces, normals = mesh.boundary_faces()
    p = mesh.nodes[faces]
    areas = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    zmin = float(mesh.nodes[:, 2].min())
    return SurfaceFaces(normals, areas, ~np.all(p[:, :, 2] <= zmin + BASE_TOL_MM, axis=1), faces)


def _face_dirs(surface: SurfaceFaces, node_dirs: np.ndarray) -> np.ndarray:
    d = node_dirs[surface.faces].mean(axis=1)
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)


def overhang_area_mm2(surface: SurfaceFaces, face_dirs: np.ndarray) -> float:
    """Area of the off-plate faces with ``n . d < -sin 45`` (``face_dirs``: one unit d per face, or one for all)."""
    dots = np.einsum("ij,ij->i", surface.normals, np.broadcast_to(face_dirs, surface.normals.shape))
    return float(surface.areas_mm2[(dots < -SIN45) & surface.off_plate].sum())


def cusp_error_mm(surface: SurfaceFaces, face_dirs: np.ndarray, thickness_mm: np.ndarray | float,
                  on_layer: np.ndarray) -> tuple[float, float]:
    """(area-weighted mean, max) staircase error over the top faces; ``on_layer`` faces have none."""
    normals = surface.normals
    top = (normals[:, 2] > 0.0) & surface.off_plate
    if not np.any(top):
        return 0.0, 0.0
    dirs = np.broadcast_to(face_dirs, normals.shape)
    cusp = np.broadcast_to(thickness_mm, normals[:, 0].shape) * np.abs(np.einsum("ij,ij->i", normals, dirs))
    cusp = np.where(on_layer, 0.0, cusp)[top]
    area = surface.areas_mm2[top]
    return float((cusp * area).sum() / area.sum()), float(cusp.max())


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-12)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def measure(field: LayerField, paths: list[CurvedPath], layers: int, nominal_mm: float,
            first_layer_mm: float, top_slope_deg: float) -> CurvedReport:
    """Every figure of :class:`CurvedReport` for a curved slice (``field`` on the part's volume mesh)."""
    z = np.array([0.0, 0.0, 1.0])
    surface = surface_faces(field.mesh)
    face_dirs = _face_dirs(surface, field.build_dir)
    over_c = overhang_area_mm2(surface, face_dirs)
    over_p = overhang_area_mm2(surface, z)
    grad = np.where(field.in_band, field.band_grad_r, field.core_grad_r)
    face_t = nominal_mm / np.maximum(grad[surface.faces].mean(axis=1), 1e-6)
    up = (surface.normals[:, 2] >= math.cos(math.radians(top_slope_deg))) & surface.off_plate
    followed = up & np.all(field.in_band[surface.faces], axis=1)
    cusp_c = cusp_error_mm(surface, face_dirs, face_t, followed)
    cusp_p = cusp_error_mm(surface, z, nominal_mm, surface.normals[:, 2] > FLAT_R)
    heights = np.concatenate([p.heights_mm for p in paths]) if paths else np.zeros(1)
    axes = np.concatenate([p.axes for p in paths]) if paths else z[None, :]
    steps = [_angle_deg(p.axes[1:], p.axes[:-1]) for p in paths if len(p.axes) > 1]
    edges = field.mesh.edges
    field_steps = _angle_deg(field.axis[edges[:, 0]], field.axis[edges[:, 1]])
    height = float(np.ptp(field.mesh.nodes[:, 2]))
    planar_layers = 1 + max(int(math.ceil((height - first_layer_mm) / nominal_mm - 1e-9)), 0)
    t_min, t_max = float(heights.min()), float(heights.max())
    return CurvedReport(
        layers=layers, planar_layers=planar_layers, overhang_mm2=over_c, planar_overhang_mm2=over_p,
        overhang_reduction_r=1.0 - over_c / over_p if over_p > 0 else 1.0,
        thickness_min_mm=t_min, thickness_max_mm=t_max, thickness_ratio_r=t_max / max(t_min, 1e-9),
        max_tilt_deg=float(np.degrees(np.arccos(np.clip(axes[:, 2], -1.0, 1.0))).max()),
        max_neighbour_deg=float(max((s.max() for s in steps), default=0.0)),
        max_field_neighbour_deg=float(field_steps.max()) if len(field_steps) else 0.0,
        cusp_mean_mm=cusp_c[0], planar_cusp_mean_mm=cusp_p[0], cusp_max_mm=cusp_c[1], planar_cusp_max_mm=cusp_p[1],
        tet_nodes=int(len(field.mesh.nodes)), tets=int(len(field.mesh.tets)))
