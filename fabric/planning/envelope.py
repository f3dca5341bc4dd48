"""The work envelope: program targets must lie over the plate and not below its surface.

Targets are the TCP (the nozzle tip) in the plate frame, whose origin is the
corner of the plate's top face at (x min, y min): a target is *off the plate*
when its x or y leaves ``[0, size]``, *below the plate* when its z is under the
top face. Both are reported as unreachable targets are (G-code line and
reason, counts by reason) and make the program not runnable, unless the user
allows it (``PlanOptions.allow_off_plate``: printing beyond the plate's edge
on purpose, or a plate whose surface the frame does not describe), in which
case they are only counted.
"""
from __future__ import annotations

import numpy as np

__all__ = ["ENV_OFF_PLATE", "ENV_BELOW_PLATE", "ENVELOPE_REASONS", "ENVELOPE_TOL_MM", "envelope_status",
           "floating_warning"]

ENV_OFF_PLATE, ENV_BELOW_PLATE = 16, 17       # statuses after the IK ones (fabric.robot.kinematics IK_*)
ENVELOPE_REASONS = {ENV_OFF_PLATE: "off the plate", ENV_BELOW_PLATE: "below the plate"}
ENVELOPE_TOL_MM = 1e-3                        # rounding of G-code coordinates and offsets
FLOAT_LAYERS = 2.0                            # a first layer more layers than this above the plate floats ...
FLOAT_MARGIN_MM = 0.5                         # ... plus this (a first layer squashed or lifted a little is fine)
FLOAT_ONE_LAYER_MM = 10.0                     # a one-layer print: its first layer higher than this floats


def envelope_status(xyz_mm: np.ndarray, rows: np.ndarray, plate_size_mm: np.ndarray) -> np.ndarray:
    """Per row: 0 inside the envelope, ``ENV_BELOW_PLATE`` or ``ENV_OFF_PLATE`` for the rows selected by the
    boolean mask ``rows`` (below the plate wins when both hold: it is a collision, not only a misplacement)."""
    sx, sy = (float(v) for v in np.asarray(plate_size_mm, dtype=float)[:2])
    tol = ENVELOPE_TOL_MM
    x, y, z = xyz_mm[:, 0], xyz_mm[:, 1], xyz_mm[:, 2]
    off = rows & ((x < -tol) | (x > sx + tol) | (y < -tol) | (y > sy + tol))
    below = rows & (z < -tol)
    out = np.zeros(len(xyz_mm), np.uint8)
    out[off] = ENV_OFF_PLATE
    out[below] = ENV_BELOW_PLATE
    return out


def floating_warning(first_layer_z_mm: float, second_layer_z_mm: float) -> str | None:
    """A warning when the part's first layer is laid well above the plate (its lowest extruding nozzle height
    more than ``FLOAT_LAYERS`` layer spacings, plus ``FLOAT_MARGIN_MM``, over the plate; the spacing is the
    second layer's height over the first): its beads would go down onto nothing, unless the operator puts an
    object there first (printing onto an insert). Found driving the cell: ``--offset 0 0 500`` planned a part
    500 mm up, runnable, without a word. None when the first layer rests on the plate (or nothing extrudes)."""
    z0, z1 = float(first_layer_z_mm), float(second_layer_z_mm)
    if not np.isfinite(z0):
        return None
    spacing = z1 - z0 if np.isfinite(z1) and z1 > z0 else None
    limit = FLOAT_LAYERS * spacing + FLOAT_MARGIN_MM if spacing is not None else FLOAT_ONE_LAYER_MM
    if z0 <= limit:
        return None
    apart = f", layers {spacing:.2f} mm apart" if spacing is not None else ""
    return (f"the first layer is laid {z0:.1f} mm above the plate{apart}: its beads go down onto nothing "
            "unless an object is placed there first (--offset Z lifts the part)")
