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

__all__ = ["ENV_OFF_PLATE", "ENV_BELOW_PLATE", "ENVELOPE_REASONS", "ENVELOPE_TOL_MM", "envelope_status"]

ENV_OFF_PLATE, ENV_BELOW_PLATE = 16, 17       # statuses after the IK ones (fabric.robot.kinematics IK_*)
ENVELOPE_REASONS = {ENV_OFF_PLATE: "off the plate", ENV_BELOW_PLATE: "below the plate"}
ENVELOPE_TOL_MM = 1e-3                        # rounding of G-code coordinates and offsets


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
