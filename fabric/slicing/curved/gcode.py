"""The multi-axis G-code dialect: every move carries the nozzle axis as I J K.

``G1 X Y Z I J K E F``: X Y Z is the nozzle tip in the plate frame (mm,
absolute), I J K the unit nozzle axis in the plate frame, pointing from the tip
up the nozzle (``I0 J0 K1`` is a vertical nozzle), E relative filament (mm).
Travels are ``G0 X Y Z I J K F``. The header states the dialect with
``; multiaxis: nozzle axis in I J K``; the rest follows the built-in writer's
conventions (no homing, temperatures, M83, ``;LAYER_CHANGE`` / ``;Z:`` /
``;HEIGHT:`` / ``;TYPE:`` markers), with ``;Z:`` the highest tip of the layer
and ``;HEIGHT:`` its nominal thickness. The axis is modal like X Y Z, but this
writer repeats it on every move so each line stands alone.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fabric.slicing.curved.paths import CurvedPath
from fabric.slicing.profile import Profile

__all__ = ["MULTIAXIS_HEADER", "GcodeTotals", "write_multiaxis"]

MULTIAXIS_HEADER = "multiaxis: nozzle axis in I J K"
TYPE_NAMES = {"perimeter": "Perimeter", "solid infill": "Solid infill", "infill": "Internal infill"}
TRAVEL_LIFT_MM = 1.0          # travels that retract leave and approach along the nozzle axis by this much


@dataclass
class GcodeTotals:
    """What the written program extrudes and how often it stops."""

    gcode: str
    filament_mm: float
    extruded_mm3: float
    retractions: int
    travel_mm: float


def _bead_areas_mm2(width_mm: float, heights_mm: np.ndarray) -> np.ndarray:
    """:func:`fabric.slicing.flow.bead_area_mm2` for many heights at once."""
    return heights_mm * (width_mm - heights_mm * (1.0 - math.pi / 4.0))


_MOVE = "G1 X{:.3f} Y{:.3f} Z{:.3f} I{:.4f} J{:.4f} K{:.4f} E{:.5f}"


def _xyz_ijk(p: np.ndarray, a: np.ndarray) -> str:
    return f"X{p[0]:.3f} Y{p[1]:.3f} Z{p[2]:.3f} I{a[0]:.4f} J{a[1]:.4f} K{a[2]:.4f}"


def write_multiaxis(layers: list[list[CurvedPath]], profile: Profile, header: list[str],
                    nominal_mm: float) -> GcodeTotals:
    """G-code of the ordered paths of every layer, in the multi-axis dialect."""
    p = profile
    out = [f"; {MULTIAXIS_HEADER}"] + [f"; {line}" for line in header + p.material_header()]
    out += [";TYPE:Custom", f"M140 S{p.bed_temp_c:g}", f"M104 S{p.nozzle_temp_c:g}",
            f"M190 S{p.bed_temp_c:g}", f"M109 S{p.nozzle_temp_c:g}",
            "G21 ; millimetres", "G90 ; absolute XYZ", "M83 ; relative E", "G92 E0"]
    travel_f, retract_f = p.travel_speed_mm_s * 60.0, p.retract_speed_mm_s * 60.0
    lift = max(p.retract_lift_mm, TRAVEL_LIFT_MM)
    area_in = p.extrusion_multiplier_r / p.filament_area_mm2
    filament = extruded = travel = 0.0
    retractions = 0
    retracted = False
    here: np.ndarray | None = None
    here_axis = np.array([0.0, 0.0, 1.0])
    for index, paths in enumerate(layers):
        if not paths:
            continue
        top = max(float(path.points_mm[:, 2].max()) for path in paths)
        out += [";LAYER_CHANGE", f";Z:{top:.3f}", f";HEIGHT:{nominal_mm:.3f}"]
        kind = ""
        for path in paths:
            start, axis0 = path.points_mm[0], path.axes[0]
            above = start + axis0 * lift
            if here is None:                    # the first bead: come down onto it along its axis
                out.append(f"G0 {_xyz_ijk(above, axis0)} F{travel_f:.0f}")
                out.append(f"G0 {_xyz_ijk(start, axis0)} F{travel_f:.0f}")
                hop = 0.0
            else:
                hop = float(np.linalg.norm(start - here))
            if hop > p.retract_min_travel_mm and here is not None:
                # retract, leave along the nozzle axis, cross, come down along the next axis
                if not retracted and p.retract_length_mm > 0:
                    out.append(f"G1 E{-p.retract_length_mm:.5f} F{retract_f:.0f}")
                    retractions += 1
                    retracted = True
                up = here + here_axis * lift
                out.append(f"G0 {_xyz_ijk(up, here_axis)} F{travel_f:.0f}")
                out.append(f"G0 {_xyz_ijk(above, axis0)} F{travel_f:.0f}")
                out.append(f"G0 {_xyz_ijk(start, axis0)} F{travel_f:.0f}")
                travel += 2.0 * lift + float(np.linalg.norm(above - up))
            elif hop > 0.0:
                out.append(f"G0 {_xyz_ijk(start, axis0)} F{travel_f:.0f}")
                travel += hop
            if retracted:
                out.append(f"G1 E{p.retract_length_mm:.5f} F{retract_f:.0f}")
                retracted = False
            if TYPE_NAMES[path.role] != kind:
                kind = TYPE_NAMES[path.role]
                out.append(f";TYPE:{kind}")
                out.append(f";WIDTH:{path.width_mm:.3f}")
            speed = p.first_layer_speed_mm_s if index == 0 else (
                p.perimeter_speed_mm_s if path.role == "perimeter" else
                p.solid_infill_speed_mm_s if path.role == "solid infill" else p.infill_speed_mm_s)
            feed = f" F{speed * 60.0:.0f}"
            seg = np.linalg.norm(np.diff(path.points_mm, axis=0), axis=1)
            volumes = seg * _bead_areas_mm2(path.width_mm, 0.5 * (path.heights_mm[1:] + path.heights_mm[:-1]))
            es = volumes * area_in
            rows = np.column_stack([path.points_mm[1:], path.axes[1:], es]).tolist()
            out.append(_MOVE.format(*rows[0]) + feed)
            out += [_MOVE.format(*row) for row in rows[1:]]
            filament += float(es.sum())
            extruded += float(volumes.sum()) * p.extrusion_multiplier_r
            here, here_axis = path.points_mm[-1], path.axes[-1]
    if not retracted and p.retract_length_mm > 0 and here is not None:
        out.append(f"G1 E{-p.retract_length_mm:.5f} F{retract_f:.0f}")
        retractions += 1
    out += [";TYPE:Custom", "M104 S0", "M140 S0", ""]
    return GcodeTotals("\n".join(out), filament, extruded, retractions, travel)
