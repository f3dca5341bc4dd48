"""Options of the curved-layer slicer and the layer-thickness bounds it derives from a profile."""
from __future__ import annotations

import math
from dataclasses import dataclass

from fabric.slicing.profile import Profile
from fabric.wire.errors import BadRequest

__all__ = ["CurvedOptions", "ThicknessBounds", "thickness_bounds", "MAX_THICKNESS_RATIO"]

MAX_THICKNESS_RATIO = 6.0       # thickest over thinnest layer, anywhere in the part


@dataclass(frozen=True)
class CurvedOptions:
    """How the curved slicer builds its fields and nozzle axes.

    ``max_tilt_deg`` is the largest angle between the nozzle axis and +z the
    cell may use; ``top_band_layers`` layers under the top surface follow it
    (0: none); a face is top surface when its normal is within
    ``top_slope_deg`` of +z. Laplacian passes over the volume mesh (at most
    ``axis_smoothing_passes``) smooth the nozzle axis until the axes at the two
    ends of every mesh edge are within ``max_neighbour_deg``. ``interior_nodes``
    sets the volume mesh's resolution (about that many lattice points inside
    the part, :mod:`.tetmesh`). ``heat_time_r`` > 0 takes the distance fields'
    directions from the heat method with that diffusion time (in squared mean
    edges), 0 from shortest paths along the mesh's edges (:mod:`.heat`).

    The nozzle axis near the plate and over the layers (:mod:`.axis`): the
    layers blend from flat to curved over the first ``plate_blend_mm``; the
    tilt allowed grows with the height over the plate for a tip of
    ``tip_radius_mm`` (a bound for any nozzle up to that radius); the axis
    stays within ``max_axis_deviation_deg`` of the layer normal, and is
    averaged along each path over ``path_axis_window_mm``.

    Creases of the core field (where fronts from two legs meet) are rounded
    within ``crease_width_mm`` by ``crease_flatten_r`` (:mod:`.crease`). The
    nozzle the axes must clear (:mod:`.reach`): a tip of
    ``nozzle_tip_radius_mm`` for ``nozzle_tip_length_mm``, a cone widening to
    ``nozzle_radius_mm`` over ``nozzle_taper_mm``, then that radius up to
    ``nozzle_reach_mm`` from the tip (the multi-axis cell's nozzle;
    ``nozzle_radius_mm`` 0: no such check).
    """

    max_tilt_deg: float = 45.0
    top_band_layers: int = 4
    top_slope_deg: float = 60.0
    axis_smoothing_passes: int = 40
    max_neighbour_deg: float = 30.0
    interior_nodes: int = 6000
    heat_time_r: float = 0.0
    plate_blend_mm: float = 3.0
    tip_radius_mm: float = 4.0
    max_axis_deviation_deg: float = 5.0
    path_axis_window_mm: float = 2.0
    crease_flatten_r: float = 0.5
    crease_width_mm: float = 3.0
    nozzle_tip_radius_mm: float = 0.35
    nozzle_tip_length_mm: float = 1.0
    nozzle_taper_mm: float = 3.0
    nozzle_radius_mm: float = 1.0
    nozzle_reach_mm: float = 10.0

    def __post_init__(self) -> None:
        checks = {"max_tilt_deg": (0.0, 89.0), "top_slope_deg": (0.0, 89.0), "heat_time_r": (0.0, 100.0),
                  "max_neighbour_deg": (1.0, 90.0), "plate_blend_mm": (0.0, 1000.0),
                  "tip_radius_mm": (0.0, 100.0), "max_axis_deviation_deg": (0.0, 90.0),
                  "path_axis_window_mm": (0.0, 100.0), "crease_flatten_r": (0.0, 1.0),
                  "crease_width_mm": (0.0, 100.0), "nozzle_tip_radius_mm": (0.0, 50.0),
                  "nozzle_tip_length_mm": (0.0, 50.0), "nozzle_taper_mm": (0.0, 100.0),
                  "nozzle_radius_mm": (0.0, 50.0), "nozzle_reach_mm": (0.0, 1000.0)}
        for key, (lo, hi) in checks.items():
            value = getattr(self, key)
            if not (math.isfinite(value) and lo <= value <= hi):
                raise BadRequest(f"curved slicing: {key} = {value} is out of range [{lo}, {hi}]", key=key, value=value)
        for key, hi_n in (("top_band_layers", 50), ("axis_smoothing_passes", 200), ("interior_nodes", 2_000_000)):
            value = getattr(self, key)
            if not 0 <= value <= hi_n:
                raise BadRequest(f"curved slicing: {key} = {value} is out of range [0, {hi_n}]", key=key, value=value)


@dataclass(frozen=True)
class ThicknessBounds:
    """The layer thicknesses the bead model accepts for a profile (mm)."""

    nominal_mm: float
    min_mm: float
    max_mm: float


def thickness_bounds(profile: Profile) -> ThicknessBounds:
    """Thinnest and thickest layer a curved slice may lay with this profile.

    The thickest is bounded by the nozzle (a bead cannot be taller than the
    nozzle's bore) and by the bead model (narrower than tall is not a bead);
    the thinnest is the thickest over :data:`MAX_THICKNESS_RATIO`, and never
    more than half the nominal layer height.
    """
    h = profile.layer_height_mm
    max_mm = min(2.0 * h, profile.nozzle_diameter_mm, 0.9 * profile.extrusion_width_mm)
    max_mm = max(max_mm, h)
    min_mm = max(max_mm / MAX_THICKNESS_RATIO, 0.01)
    return ThicknessBounds(nominal_mm=h, min_mm=min(min_mm, 0.5 * h), max_mm=max_mm)
