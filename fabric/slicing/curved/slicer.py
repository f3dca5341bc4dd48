"""The curved-layer slicer: placed mesh + profile -> multi-axis G-code and its measured figures.

Steps: tetrahedralise the part (:mod:`.tetmesh`); solve the core and top-band
fields and the nozzle axes (:mod:`.field`: the layers leaning no further than
the nozzle can follow them, :mod:`.lean`; every axis one the cell's arm holds
where it is, when the slicer knows the cell, :mod:`.cell_tilt`); cut the core
field's level sets one layer apart (the first at the first-layer height), each
clipped to below the top band and thinned where it would leave a larger
staircase on an upward face than planar layers do, then the band's level sets
(:mod:`.isosurface`); lay perimeters and infill on each (:mod:`.paths`); write
the multi-axis dialect (:mod:`.gcode`); measure the result against planar
slicing (:mod:`.metrics`).
"""
from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh

from fabric.slicing.curved.axis import TiltLimits, limit_deviation, smooth_along
from fabric.slicing.curved.cell_tilt import CellTilts
from fabric.slicing.curved.field import LayerField, build_field
from fabric.slicing.curved.gcode import write_multiaxis
from fabric.slicing.curved.isosurface import Surface, clip_surface, iso_surface
from fabric.slicing.curved.metrics import (
    SIN45,
    TOP_MIN_NZ,
    CurvedReport,
    Layering,
    measure,
    planar_thickness_mm,
    surface_faces,
)
from fabric.slicing.curved.options import CurvedOptions, ThicknessBounds, thickness_bounds
from fabric.slicing.curved.paths import CLIP, THICK, CurvedPath, LayerSpec, layer_paths, order_paths
from fabric.slicing.curved.reach import NozzleReach
from fabric.slicing.curved.tetmesh import tetrahedralise
from fabric.slicing.profile import Profile
from fabric.wire.errors import SlicerError

__all__ = ["CurvedSlice", "slice_curved", "MAX_LAYERS", "PROGRESS_STAGES"]

MAX_LAYERS = 20000
REFITS = 4                  # field-step refits per layer to keep its thickness within bounds
# the progress fraction reported when each step is done (the toolpaths go up layer by layer in between)
PROGRESS_STAGES = (("volume mesh", 0.15), ("fields", 0.35), ("layer surfaces", 0.45), ("toolpaths", 0.90),
                   ("figures", 0.93), ("G-code", 1.0))
CUSP_MARGIN_R = 0.95        # core layers aim this far under planar's staircase: the field is linear per element
CORE_TUCK_MM = 0.05              # the core's beads end this far under the band's bottom (:func:`_core_layer`)
BAND_BASE_DEVIATION_DEG = 2.0     # the nozzle axis off the layer normal on the band's first layer, at most


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


def _held_axes(paths: list[CurvedPath], tilts: TiltLimits, opts: CurvedOptions, max_deviation_deg: float,
               reach: NozzleReach) -> list[CurvedPath]:
    """The axis rules (:mod:`.axis`) held exactly at every point of ``paths``, where the tip rides: the field's
    axes are interpolated between mesh nodes, which hold them only at the nodes. Then the nozzle's reach
    (:mod:`.reach`) turns those that would run into the beads."""
    for path in paths:
        axes = smooth_along(path.points_mm, path.axes, path.closed, opts.path_axis_window_mm)
        axes = limit_deviation(axes, path.normals, max_deviation_deg)
        path.axes = tilts.hold(path.points_mm, axes)
    return reach.hold(paths, tilts)


def _core_layer(fld: LayerField, attrs: np.ndarray, level: float, step: float) -> Surface:
    """The core's level set ``level`` (a layer ``step`` of field thick), clipped where it meets the band: a core
    bead stands half its layer over the layer's mid-surface, so the mid-surface ends that much (and
    :data:`CORE_TUCK_MM`) under the band's bottom (``attrs``' CLIP column: the distance under it)."""
    s = iso_surface(fld.mesh.tets, fld.d_base_mm, level, attrs)
    if fld.band_mm <= 0 or len(s.tris) == 0:
        return s
    s.attrs[:, CLIP] -= 0.5 * step * s.attrs[:, THICK] + CORE_TUCK_MM
    return clip_surface(s, CLIP, 0.0)


def _cusp_caps(fld: LayerField, nominal_mm: float, first_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every upward face that core layers cut: its core field range (lo, hi) and the largest field step
    that keeps its staircase error within planar slicing's on a face of the same tilt (of 45 degrees if it is
    steeper: planar layers leave next to nothing on a near-vertical wall, which no tilted layer could match).

    A core layer of field step ``s`` is ``s / |grad|`` thick at a corner, so its
    step there is ``s |n . d| / |grad|``; planar layers leave ``t_planar n_z``
    (:func:`.metrics.planar_thickness_mm`). Where the field is weak (``|grad| < 1``:
    the layers are thicker than their step) or tilted towards the face's
    normal, the cap is below the nominal step.
    """
    surface = surface_faces(fld.mesh)
    faces, normals = surface.faces, surface.normals
    core = ~fld.in_band[faces]
    cut = (normals[:, 2] > TOP_MIN_NZ) & surface.off_plate & core.any(axis=1)
    planar = planar_thickness_mm(surface, fld.mesh.nodes, nominal_mm, first_mm) * np.maximum(normals[:, 2], SIN45)
    planar *= CUSP_MARGIN_R
    slope = np.abs(np.einsum("fk,fck->fc", normals, fld.core_dir[faces]))
    allowed = planar[:, None] * fld.core_grad_r[faces] / np.maximum(slope, 1e-9)
    allowed = np.where(core, allowed, np.inf).min(axis=1)
    d = fld.d_base_mm[faces]
    return d.min(axis=1)[cut], d.max(axis=1)[cut], allowed[cut]


def _layer_surfaces(fld: LayerField, first_mm: float, bounds: ThicknessBounds,
                    ) -> tuple[list[tuple[Surface, bool]], Layering]:
    """Mid-surfaces of every layer, bottom to top: (surface, in the top band), and where they lie.

    Core layers are ``nominal`` apart in the field (the first one
    ``first_mm``), each step shortened where an upward face it cuts would get
    a larger staircase than planar layers give it (:func:`_cusp_caps`), and where
    the field's gradient is weak enough to make the layer thicker than the
    bounds allow. The band's layers split its depth evenly into layers that fit
    the bounds everywhere in it.
    """
    nodes = fld.mesh.nodes
    under_band = fld.band_clip_mm / np.maximum(fld.band_grad_r, 1e-6)       # about the distance under its bottom
    core_attrs = np.column_stack([nodes, fld.core_dir, fld.axis, 1.0 / np.maximum(fld.core_grad_r, 1e-6),
                                  np.minimum(under_band, 1e9), np.minimum(fld.under_top_mm, 1e9)])
    core = fld.d_base_mm if fld.band_mm <= 0 else np.where(fld.in_band, -np.inf, fld.d_base_mm)
    top = float(core[np.isfinite(core)].max()) if np.any(np.isfinite(core)) else 0.0
    out: list[tuple[Surface, bool]] = []
    cap_lo, cap_hi, cap_step = _cusp_caps(fld, bounds.nominal_mm, first_mm)
    steps: list[tuple[float, float]] = []
    lo, want = 0.0, first_mm
    for _ in range(MAX_LAYERS):
        if lo >= top:
            break
        cut = (cap_hi >= lo) & (cap_lo <= lo + want)
        if np.any(cut):                 # below the thinnest layer the bounds allow, the bounds win (_fit_step)
            want = max(min(want, float(cap_step[cut].min())), bounds.min_mm)
        s = _core_layer(fld, core_attrs, lo + 0.5 * want, want)
        step = want
        for _refit in range(REFITS):               # the shorter step's level set may be weaker still
            fitted = _fit_step(s, step, bounds) if len(s.tris) else step
            if fitted >= step * 0.999:
                break
            step = fitted
            s = _core_layer(fld, core_attrs, lo + 0.5 * step, step)
        s.attrs[:, THICK] *= step
        if len(s.tris):
            out.append((s, False))
        steps.append((lo, step))
        lo, want = lo + step, bounds.nominal_mm
    else:
        raise SlicerError(f"curved slicing: more than {MAX_LAYERS} layers", reason="too_many_layers")
    band_step = 0.0
    if fld.band_mm > 0:
        band_attrs = np.column_stack([nodes, fld.band_dir, fld.axis, 1.0 / np.maximum(fld.band_grad_r, 1e-6),
                                      fld.band_clip_mm, np.zeros(len(nodes))])
        inv = band_attrs[fld.in_band, THICK] if np.any(fld.in_band) else np.ones(1)
        weakest, strongest = float(inv.max()), float(inv.min())
        # no thicker than the bounds allow where the band's gradient is weakest, and never thinner than the
        # thinnest layer where it is strongest (a node of near-zero gradient asked for a million layers: 24 GB
        # on a 100k-triangle dome; capped by the thinnest layer where the gradient is 1, the band's layers came
        # out 0.051 mm where it is stronger, under the bounds)
        k = max(int(round(fld.band_mm / bounds.nominal_mm)),
                min(int(np.ceil(fld.band_mm * weakest / bounds.max_mm - 1e-9)),
                    int(np.floor(fld.band_mm * strongest / bounds.min_mm + 1e-9))), 1)
        band_step = step = fld.band_mm / k
        for j in range(k):
            s = clip_surface(iso_surface(fld.mesh.tets, fld.d_top_mm, fld.band_mm - (j + 0.5) * step, band_attrs),
                             CLIP, 0.0, keep_above=False)
            s.attrs[:, THICK] *= step
            if len(s.tris):
                out.append((s, True))
    core_lo, core_step = np.array(steps).reshape(-1, 2).T
    return out, Layering(core_lo, core_step, band_step)


def slice_curved(part: trimesh.Trimesh, profile: Profile, options: CurvedOptions | None = None,
                 progress: Callable[[float], None] | None = None, cell: Any = None) -> CurvedSlice:
    """Slice a placed, watertight part into curved layers (see the module docstring). Given the ``cell`` it
    will be printed on (a :class:`fabric.robot.cell.Cell`; the part placed in its plate frame), every nozzle
    axis is one its arm holds there (:mod:`.cell_tilt`).

    Raises MeshError (not a closed solid, or not meshable) and SlicerError.
    """
    t0 = time.perf_counter()
    opts = options or CurvedOptions()
    report = progress or (lambda _f: None)
    bounds = thickness_bounds(profile)
    tet = tetrahedralise(part, opts.interior_nodes)
    done = dict(PROGRESS_STAGES)
    report(done["volume mesh"])
    plate_z = float(tet.nodes[:, 2].min())
    arm = None if cell is None else CellTilts.of_cell(cell, np.asarray(part.bounds), opts.max_tilt_deg)
    tilts = TiltLimits(plate_z, profile.first_layer_height_mm, opts.tip_radius_mm, opts.max_tilt_deg, arm)
    fld = build_field(tet, opts, bounds.nominal_mm, side_margin_mm=profile.extrusion_width_mm,
                      first_layer_mm=profile.first_layer_height_mm, tilts=tilts)
    report(done["fields"])
    surfaces, layering = _layer_surfaces(fld, profile.first_layer_height_mm, bounds)
    report(done["layer surfaces"])
    layers: list[list[CurvedPath]] = []
    here = np.array([0.0, 0.0, 0.0])
    first_band = next((i for i, (_s, in_band) in enumerate(surfaces) if in_band), -1)
    reach = NozzleReach(opts)
    for i, (surface, in_band) in enumerate(surfaces):
        spec = LayerSpec(index=i, solid=in_band or i < profile.bottom_solid_layers,
                         infill_angle_deg=profile.infill_angle_deg + 90.0 * (i % 2))
        # the band's first layer lies on the ends of many core layers, not on one layer: its tip must not dig
        deviation = min(opts.max_axis_deviation_deg, BAND_BASE_DEVIATION_DEG) if i == first_band else \
            opts.max_axis_deviation_deg
        paths = _held_axes(layer_paths(surface, spec, profile), tilts, opts, deviation, reach)
        ordered = order_paths(paths, here)
        if ordered:                         # a sliver of a level set too small for a bead prints nothing
            here = ordered[-1].points_mm[-1]
            for path in ordered:
                path.layer = len(layers)
            layers.append(ordered)
        step_r = (done["toolpaths"] - done["layer surfaces"]) / max(len(surfaces), 1)
        report(done["layer surfaces"] + step_r * (i + 1))
    flat = [p for layer in layers for p in layer]
    if not flat:
        raise SlicerError("curved slicing produced no toolpaths (part thinner than a bead?)", reason="empty")
    figures = measure(fld, flat, len(layers), layering, bounds.nominal_mm, profile.first_layer_height_mm)
    report(done["figures"])
    warnings = []
    if figures.thickness_min_mm < bounds.min_mm - 1e-9 or figures.thickness_max_mm > bounds.max_mm + 1e-9:
        warnings.append(f"curved: layer thickness {figures.thickness_min_mm:.3f}..{figures.thickness_max_mm:.3f} mm "
                        f"leaves the profile's bounds {bounds.min_mm:.3f}..{bounds.max_mm:.3f} mm")
    if reach.blocked:
        warnings.append(f"curved: at {reach.blocked} of {reach.checked} points no nozzle axis clears the beads "
                        f"laid before (the collision check of the planned program decides)")
    header = ["generated by am-fabric builtin curved-layer slicer", f"profile: {profile.name}",
              f"curved: max_tilt_deg = {opts.max_tilt_deg:g}"] + figures.header_lines()
    totals = write_multiaxis(layers, profile, header, bounds.nominal_mm, opts.tip_radius_mm)
    report(done["G-code"])
    elapsed = time.perf_counter() - t0
    figures = dataclasses.replace(figures, elapsed_s=elapsed)
    return CurvedSlice(gcode=totals.gcode, layers=len(layers), extruded_mm3=totals.extruded_mm3,
                       filament_mm=totals.filament_mm, retractions=totals.retractions, travel_mm=totals.travel_mm,
                       report=figures, paths=layers, warnings=warnings)
