"""Placing a part on the plate (bed coordinates) and checking it fits the plate and build volume.

Bed coordinates have their origin at a corner of the plate, X and Y along its
edges, Z up from its surface; every back-end writes G-code in these
coordinates. A placement rotates the part about Z, drops it onto the plate
(lowest point at Z = 0) and moves the centre of its XY bounding box to
``center_xy_mm`` (the centre of the plate when None). The check then says
which dimension overflows and by how much. A part modelled wholly off the
plate and moved to its centre (no centre asked for) is moved with a note
saying from where, so the user learns that the file's own position was not
kept.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from fabric.wire.errors import PlacementError

__all__ = ["Placement", "place_mesh"]


@dataclass(frozen=True)
class Placement:
    """Where the part goes: bbox centre on the plate (mm; None = plate centre) and a Z rotation."""

    center_xy_mm: tuple[float, float] | None = None
    rotate_z_deg: float = 0.0


def place_mesh(mesh: trimesh.Trimesh, placement: Placement | None,
               plate_size_mm: tuple[float, float] = (250.0, 250.0),
               build_height_mm: float = 250.0, notes: list[str] | None = None) -> trimesh.Trimesh:
    """A placed copy of ``mesh`` in bed coordinates; PlacementError if it does not fit. ``notes`` gets
    a line when a part modelled off the plate was re-centred on it (see the module docstring)."""
    placement = placement or Placement()
    plate = np.asarray(plate_size_mm, dtype=np.float64)
    if plate.shape != (2,) or not np.isfinite(plate).all() or (plate <= 0).any() or build_height_mm <= 0:
        raise PlacementError(f"invalid plate {plate_size_mm} x {build_height_mm} mm",
                             plate_size_mm=list(plate_size_mm), build_height_mm=build_height_mm)
    out = mesh.copy()
    if placement.rotate_z_deg:
        out.apply_transform(trimesh.transformations.rotation_matrix(
            math.radians(placement.rotate_z_deg), (0.0, 0.0, 1.0)))
    lo, hi = out.bounds
    centre = plate / 2.0 if placement.center_xy_mm is None else np.asarray(placement.center_xy_mm, float)
    if centre.shape != (2,) or not np.isfinite(centre).all():
        raise PlacementError(f"invalid placement centre {placement.center_xy_mm}",
                             center_xy_mm=placement.center_xy_mm)
    shift = np.array([centre[0] - (lo[0] + hi[0]) / 2.0, centre[1] - (lo[1] + hi[1]) / 2.0, -lo[2]])
    if notes is not None and placement.center_xy_mm is None and _off_plate(lo, hi, plate):
        notes.append(f"the model lies off the {plate[0]:g} x {plate[1]:g} mm plate (X {lo[0]:.1f} to "
                     f"{hi[0]:.1f}, Y {lo[1]:.1f} to {hi[1]:.1f} mm): centred on the plate, moved by "
                     f"({shift[0]:.1f}, {shift[1]:.1f}) mm (--center X Y places it elsewhere)")
    out.apply_translation(shift)
    lo, hi = out.bounds
    size = hi - lo
    # The part itself larger than the plate / volume: say so before blaming the centre.
    for axis, name, limit in ((0, "X", plate[0]), (1, "Y", plate[1]), (2, "Z", build_height_mm)):
        if size[axis] > limit + 1e-9:
            what = "build height" if axis == 2 else f"plate {name} size"
            raise PlacementError(f"part is {size[axis]:.2f} mm in {name}, {size[axis] - limit:.2f} mm more "
                                 f"than the {what} of {limit:.2f} mm", axis=name, size_mm=float(size[axis]),
                                 limit_mm=float(limit), excess_mm=float(size[axis] - limit))
    for axis, name in ((0, "X"), (1, "Y")):
        if lo[axis] < -1e-9:
            raise PlacementError(f"part sticks out of the plate by {-lo[axis]:.2f} mm at {name} min "
                                 f"(centre {centre[axis]:.2f} mm is too close to the edge)", axis=name,
                                 side="min", excess_mm=float(-lo[axis]))
        if hi[axis] > plate[axis] + 1e-9:
            raise PlacementError(f"part sticks out of the plate by {hi[axis] - plate[axis]:.2f} mm at "
                                 f"{name} max (centre {centre[axis]:.2f} mm is too close to the edge)",
                                 axis=name, side="max", excess_mm=float(hi[axis] - plate[axis]))
    return out


def _off_plate(lo: np.ndarray, hi: np.ndarray, plate: np.ndarray) -> bool:
    """The part's XY bounding box does not touch the plate at all."""
    return bool(hi[0] < 0.0 or hi[1] < 0.0 or lo[0] > plate[0] or lo[1] > plate[1])
