"""The curved-layer slicer: placed mesh + profile -> multi-axis G-code and its measured figures.

Steps: tetrahedralise the part (:mod:`.tetmesh`); solve the core and top-band
fields and the nozzle axes (:mod:`.field`); cut the core field's level sets
one layer apart (the first at the first-layer height), each clipped to below
the top band, then the band's level sets (:mod:`.isosurface`); lay perimeters
and infill on each (:mod:`.paths`); write the multi-axis dialect
(:mod:`.gcode`); measure the result against planar slicing (:mod:`.metrics`).
"""
from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import trimesh

from fabric.slicing.curved.field import LayerField, build_field
from fabric.slicing.curved.gcode import write_multiaxis
from fabric.slicing.curved.isosurface import Surface, clip_surface, iso_surface
from fabric.slicing.curved.metrics import CurvedReport, measure
from fabric.slicing.curved.options import CurvedOptions, ThicknessBounds, thickness_bounds
from fabric.slicing.curved.paths import CLIP, THICK, CurvedPath, LayerSpec, layer_paths, order_paths
from fabric.slicing.curved.tetmesh import tetrahedralise
from fabric.slicing.profile import Profile
from fabric.wire.errors import SlicerError

__all__ = ["CurvedSlice", "slice_curved", "MAX_LAYERS"]

MAX_LAYERS = 20000
REFITS = 4                  # field-step refits per layer to keep its thickness within bounds


@dataclass
class CurvedSlice:
    """A curved slice: the G-code, its totals, its paths per layer and the measured report."""

    gcode: str
    layers: int
    extruded_mm3: float
    filament_mm: float
    retractions: int
    travel_mm: float
    report: CurvedReport
    paths: list[list[CurvedPath]]
    warnings: list[str] = field(default_factory=list)


def _fit_step(surface: Surface, want_mm: float, bounds: ThicknessBounds) -> float:
    """The field step that keeps a layer's thickness (step / |grad|, THICK holds 1 / |grad|) within bounds.

    The step shrinks until the thickest point fits under the maximum; the
    thinnest point is then kept above the minimum if that is still possible
    (when both cannot hold, the layer is too uneven and the maximum wins).
    """
    inv = surface.attrs[:, THICK]
    step = min(want_mm, bounds.max_mm / float(inv.max()))
    floor = bounds.min_mm / float(inv.min())
    return max(step, min(floor, bounds.max_mm / float(inv.max())), 1e-3)


def _core_layer(fld: LayerField, attrs: np.ndarray, level: float) -> Surface:
    s = iso_surface(fld.mesh.tets, fld.d_base_mm, level, attrs)
    return clip_surface(s, CLIP, 0.0) if fld.band_mm > 0 else s


def _layer_surfaces(fld: LayerField, first_mm: float, bounds: ThicknessBounds) -> list[tuple[Surface, bool]]:
    """Mid-surfaces of every layer, bottom to top: (surface, in the top band).

    Core layers are ``nominal`` apart in the field (the first one
    ``first_mm``), each step shortened where the field's gradient is weak
    enough to make the layer thicker than the bounds allow. The band's layers
    split its depth evenly into layers that fit the bounds everywhere in it.
    """
    nodes = fld.mesh.nodes
    core_attrs = np.column_stack([nodes, fld.core_dir, fld.axis, 1.0 / np.maximum(fld.core_grad_r, 1e-6),
                                  np.minimum(fld.band_clip_mm, 1e9)])
    core = fld.d_base_mm if fld.band_mm <= 0 else np.where(fld.in_band, -np.inf, fld.d_base_mm)
    top = float(core[np.isfinite(core)].max()) if np.any(np.isfinite(core)) else 0.0
    out: list[tuple[Surface, bool]] = []
    lo, want = 0.0, first_mm
    for _ in range(MAX_LAYERS):
        if lo >= top:
            break
        s = _core_layer(fld, core_attrs, lo + 0.5 * want)
        step = want
        for _refit in range(REFITS):               # the shorter step's level set may be weaker still
            fitted = _fit_step(s, step, bounds) if len(s.tris) else step
            if fitted >= step * 0.999:
                break
            step = fitted
            s = _core_layer(fld, core_attrs, lo + 0.5 * step)
        s.attrs[:, THICK] *= step
        if len(s.tris):
            out.append((s, False))
        lo, want = lo + step, bounds.nominal_mm
    else:
        raise SlicerError(f"curved slicing: more than {MAX_LAYERS} layers", reason="too_many_layers")
    if fld.band_mm > 0:
        band_attrs = np.column_stack([nodes, fld.band_dir, fld.axis, 1.0 / np.maximum(fld.band_grad_r, 1e-6),
                                      fld.band_clip_mm])
        weakest = float(band_attrs[fld.in_band, THICK].max()) if np.any(fld.in_band) else 1.0
        k = max(int(round(fld.band_mm / bounds.nominal_mm)),
                int(np.ceil(fld.band_mm * weakest / bounds.max_mm - 1e-9)), 1)
        step = fld.band_mm / k
        for j in range(k):
            s = clip_surface(iso_surface(fld.mesh.tets, fld.d_top_mm, fld.band_mm - (j + 0.5) * step, band_attrs),
                             CLIP, 0.0, keep_above=False)
            s.attrs[:, THICK] *= step
            if len(s.tris):
                out.append((s, True))
    return out


def slice_curved(part: trimesh.Trimesh, profile: Profile, options: CurvedOptions | None = None,
                 progress: Callable[[float], None] | None = None) -> CurvedSlice:
    """Slice a placed, watertight part into curved layers (see the module docstring).

    Raises MeshError (not a closed solid, or not meshable) and SlicerError.
    """
    t0 = time.perf_counter()
    opts = options or CurvedOptions()
    report = progress or (lambda _f: None)
    bounds = thickness_bounds(profile)
    tet = tetrahedralise(part, opts.interior_nodes)
    report(0.15)
    fld = build_field(tet, opts, bounds.nominal_mm, side_margin_mm=profile.extrusion_width_mm)
    report(0.35)
    surfaces = _layer_surfaces(fld, profile.first_layer_height_mm, bounds)
    report(0.45)
    layers: list[list[CurvedPath]] = []
    here = np.array([0.0, 0.0, 0.0])
    for i, (surface, in_band) in enumerate(surfaces):
        spec = LayerSpec(index=i, solid=in_band or i < profile.bottom_solid_layers,
                         infill_angle_deg=profile.infill_angle_deg + 90.0 * (i % 2))
        ordered = order_paths(layer_paths(surface, spec, profile), here)
        if ordered:                         # a sliver of a level set too small for a bead prints nothing
            here = ordered[-1].points_mm[-1]
            for path in ordered:
                path.layer = len(layers)
            layers.append(ordered)
        report(0.45 + 0.45 * (i + 1) / max(len(surfaces), 1))
    flat = [p for layer in layers for p in layer]
    if not flat:
        raise SlicerError("curved slicing produced no toolpaths (part thinner than a bead?)", reason="empty")
    figures = measure(fld, flat, len(layers), bounds.nominal_mm, profile.first_layer_height_mm,
                      opts.top_slope_deg)
    warnings = []
    if figures.thickness_min_mm < bounds.min_mm - 1e-9 or figures.thickness_max_mm > bounds.max_mm + 1e-9:
        warnings.append(f"curved: layer thickness {figures.thickness_min_mm:.3f}..{figures.thickness_max_mm:.3f} mm "
                        f"leaves the profile's bounds {bounds.min_mm:.3f}..{bounds.max_mm:.3f} mm")
    header = ["generated by am-fabric builtin curved-layer slicer", f"profile: {profile.name}",
              f"curved: max_tilt_deg = {opts.max_tilt_deg:g}"] + figures.header_lines()
    totals = write_multiaxis(layers, profile, header, bounds.nominal_mm)
    report(1.0)
    elapsed = time.perf_counter() - t0
    figures = dataclasses.replace(figures, elapsed_s=elapsed)
    return CurvedSlice(gcode=totals.gcode, layers=len(layers), extruded_mm3=totals.extruded_mm3,
                       filament_mm=totals.filament_mm, retractions=totals.retractions, travel_mm=totals.travel_mm,
                       report=figures, paths=layers, warnings=warnings)
