"""Measured figures of a curved slice beside planar slicing of the same part.

* Overhang (the 45 degree rule): a boundary face overhangs when ``n . d <
  -sin 45``, ``n`` its outward normal and ``d`` the local build direction (the
  field's gradient for curved layers, +z for planar ones). Faces lying on the
  plate are supported by it and never count.
* Cusp (staircase) error of the top surface, i.e. the faces that look up
  (``n_z > 0``, off the plate; ``1e-6`` keeps vertical walls out): where layers of thickness ``t`` cut a surface at
  an angle, the step's corner stands ``t |n . d|`` off the surface (a step of
  height ``t`` under a slope of angle ``b`` sticks out ``t cos b``). A face that
  *is* a layer's surface has none: a flat face for planar layers, a face of the
  followed top surface for curved ones. ``t`` is the thickness of the layers
  that cut the face as sliced: planar, the first-layer height for a face that
  reaches into the first layer and the layer height above; curved, the step of
  the field's layer at each corner over the field's gradient there. A curved
  face is measured at each corner with that corner's field (core or band), so
  a face where the band ends is not given a direction halfway between the two;
  the face's error is the largest of its corners' (the mean uses their mean).
  Reported as the area-weighted mean and the maximum over the top faces.
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

__all__ = ["CurvedReport", "Layering", "SurfaceFaces", "surface_faces", "overhang_area_mm2", "corner_cusps_mm",
           "cusp_error_mm", "planar_thickness_mm", "measure"]

SIN45 = math.sin(math.radians(45.0))
FLAT_R = 0.999            # |n_z| above this: a horizontal face
TOP_MIN_NZ = 1e-6         # n_z above this: a face that looks up (below: a vertical wall, give or take rounding)


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
    max_axis_deviation_deg: float = 0.0      # largest angle between the nozzle axis and the layer normal
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


@dataclass(frozen=True)
class Layering:
    """Where a curved slice's layers lie in its fields (mm of field value): the bottom and the step of every
    core layer, bottom up, and the step of the band's layers (0 without a band)."""

    core_lo_mm: np.ndarray
    core_step_mm: np.ndarray
    band_step_mm: float

    def core_step(self, d_mm: np.ndarray) -> np.ndarray:
        """The step of the core layer that holds each core field value (the first's below, the last's above)."""
        if len(self.core_step_mm) == 0:
            return np.zeros_like(d_mm)
        k = np.searchsorted(self.core_lo_mm, d_mm, side="right") - 1
        return self.core_step_mm[np.clip(k, 0, len(self.core_step_mm) - 1)]


def planar_thickness_mm(surface: SurfaceFaces, nodes: np.ndarray, nominal_mm: float,
                        first_layer_mm: float) -> np.ndarray:
    """(f,) the thickest planar layer that cuts each face: the first layer's for a face reaching below its
    top, the nominal above."""
    z = nodes[surface.faces][:, :, 2] - float(nodes[:, 2].min())
    reaches_first = z.min(axis=1) < first_layer_mm
    above_first = z.max(axis=1) > first_layer_mm
    return np.maximum(np.where(reaches_first, first_layer_mm, 0.0), np.where(above_first, nominal_mm, 0.0))


def corner_cusps_mm(field: LayerField, surface: SurfaceFaces, layering: Layering) -> np.ndarray:
    """(f, 3) the staircase error of each face at each corner, with that corner's field: 0 in the band on a
    face the band follows (top surface), else ``t |n . d|`` with the corner's layer thickness and direction."""
    faces, normals = surface.faces, surface.normals
    t_core = layering.core_step(field.d_base_mm) / np.maximum(field.core_grad_r, 1e-6)
    c_core = t_core[faces] * np.abs(np.einsum("fk,fck->fc", normals, field.core_dir[faces]))
    t_band = layering.band_step_mm / np.maximum(field.band_grad_r, 1e-6)
    c_band = t_band[faces] * np.abs(np.einsum("fk,fck->fc", normals, field.band_dir[faces]))
    c_band = np.where(field.followed[:, None], 0.0, c_band)
    return np.where(field.in_band[faces], c_band, c_core)


def cusp_error_mm(surface: SurfaceFaces, corner_mm: np.ndarray) -> tuple[float, float]:
    """(area-weighted mean, max) staircase error over the top faces from each face's corner errors (f, 3),
    or one value per face (f,)."""
    top = (surface.normals[:, 2] > TOP_MIN_NZ) & surface.off_plate
    if not np.any(top):
        return 0.0, 0.0
    corners = corner_mm.reshape(len(corner_mm), -1)[top]
    area = surface.areas_mm2[top]
    return float((corners.mean(axis=1) * area).sum() / area.sum()), float(corners.max())


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-12)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def measure(field: LayerField, paths: list[CurvedPath], layers: int, layering: Layering, nominal_mm: float,
            first_layer_mm: float) -> CurvedReport:
    """Every figure of :class:`CurvedReport` for a curved slice (``field`` on the part's volume mesh)."""
    z = np.array([0.0, 0.0, 1.0])
    surface = surface_faces(field.mesh)
    face_dirs = _face_dirs(surface, field.build_dir)
    over_c = overhang_area_mm2(surface, face_dirs)
    over_p = overhang_area_mm2(surface, z)
    cusp_c = cusp_error_mm(surface, corner_cusps_mm(field, surface, layering))
    planar_t = planar_thickness_mm(surface, field.mesh.nodes, nominal_mm, first_layer_mm)
    cusp_p = cusp_error_mm(surface, np.where(surface.normals[:, 2] > FLAT_R, 0.0,
                                             planar_t * np.abs(surface.normals[:, 2])))
    heights = np.concatenate([p.heights_mm for p in paths]) if paths else np.zeros(1)
    axes = np.concatenate([p.axes for p in paths]) if paths else z[None, :]
    normals = np.concatenate([p.normals for p in paths]) if paths else z[None, :]
    steps = np.zeros(0)
    if paths:
        within = np.ones(len(axes) - 1, dtype=bool)      # consecutive points of one path, not across paths
        within[np.cumsum([len(p.axes) for p in paths])[:-1] - 1] = False
        steps = _angle_deg(axes[1:], axes[:-1])[within]
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
        max_neighbour_deg=float(steps.max()) if len(steps) else 0.0,
        max_field_neighbour_deg=float(field_steps.max()) if len(field_steps) else 0.0,
        cusp_mean_mm=cusp_c[0], planar_cusp_mean_mm=cusp_p[0], cusp_max_mm=cusp_c[1], planar_cusp_max_mm=cusp_p[1],
        tet_nodes=int(len(field.mesh.nodes)), tets=int(len(field.mesh.tets)),
        max_axis_deviation_deg=float(_angle_deg(axes, normals).max()))
