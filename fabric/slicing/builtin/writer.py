"""G-code writer: absolute XYZ in bed coordinates, relative E (M83), PrusaSlicer-style markers.

Every extruding move carries ``E = length * bead_area * multiplier /
filament_area`` (mm of filament), with the bead area of
:mod:`fabric.slicing.flow` (times ``flow_r`` for bridges; a gap fill gives
each segment its own width). A travel follows the path and the retraction
decision of the layer's router (:mod:`.travel`); without one, travels longer
than ``retract_min_travel_mm`` retract. A retraction also lifts by
``retract_lift_mm`` when set; the next bead de-retracts first. The writer
counts retractions and travel length as it writes them. Layers start with ``;LAYER_CHANGE``, ``;Z:``, ``;HEIGHT:`` and
features with ``;TYPE:`` (``External perimeter``, ``Perimeter``, ``Solid
infill``, ``Top solid infill``, ``Internal infill``, ``Bridge infill``, ``Gap fill``,
``Skirt/Brim``), so one
planner reads this and PrusaSlicer / Slic3r output alike. The start has no
homing: temperatures, then M83 and G92 E0.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from fabric.slicing.flow import bead_area_mm2
from fabric.slicing.profile import Profile

__all__ = ["GcodeWriter", "Router"]

# (start, end) -> (travel path from start to end, retract before it?)
Router = Callable[[tuple[float, float], tuple[float, float]], tuple[np.ndarray, bool]]


class GcodeWriter:
    """Accumulates G-code text and the totals of what it extrudes."""

    def __init__(self, profile: Profile) -> None:
        self.p = profile
        self.out: list[str] = []
        self.x = math.nan
        self.y = math.nan
        self.z = 0.0
        self.retracted = False
        self.kind = ""
        self.width = 0.0
        self.feed = 0.0
        self.filament_mm = 0.0          # E on extruding moves
        self.net_filament_mm = 0.0      # including retractions
        self.by_type: dict[str, float] = {}
        self.retractions = 0
        self.travel_mm = 0.0
        self.router: Router | None = None    # set per layer by the slicer
        self._travel_f = profile.travel_speed_mm_s * 60.0
        self._retract_f = profile.retract_speed_mm_s * 60.0
        self._e_cache: dict[tuple[float, float], float] = {}

    # -- program frame -------------------------------------------------------------------------
    def start(self, comment_lines: list[str]) -> None:
        """Header comments, temperatures (no homing), relative E."""
        p = self.p
        self.out += [f"; {line}" for line in comment_lines]
        self.out += [";TYPE:Custom", f"M140 S{p.bed_temp_c:g}", f"M104 S{p.nozzle_temp_c:g}",
                     f"M190 S{p.bed_temp_c:g}", f"M109 S{p.nozzle_temp_c:g}",
                     "G21 ; millimetres", "G90 ; absolute XYZ", "M83 ; relative E", "G92 E0"]

    def end(self) -> None:
        """Retract and switch the heaters off (no homing, no motor release)."""
        self._retract()
        self.out += [";TYPE:Custom", "M104 S0", "M140 S0"]

    def layer(self, z_mm: float, height_mm: float) -> None:
        """Layer markers and the Z move to the layer's print height."""
        self.out += [";LAYER_CHANGE", f";Z:{z_mm:.3f}", f";HEIGHT:{height_mm:.3f}",
                     f"G1 Z{z_mm:.3f} F{self._travel_f:.0f}"]
        self.z = z_mm
        self.kind = ""

    # -- motion --------------------------------------------------------------------------------
    def _retract(self) -> None:
        if self.retracted or self.p.retract_length_mm <= 0:
            return
        self.out.append(f"G1 E{-self.p.retract_length_mm:.5f} F{self._retract_f:.0f}")
        self.net_filament_mm -= self.p.retract_length_mm
        self.retracted = True
        self.retractions += 1

    def _unretract(self) -> None:
        if not self.retracted:
            return
        self.out.append(f"G1 E{self.p.retract_length_mm:.5f} F{self._retract_f:.0f}")
        self.net_filament_mm += self.p.retract_length_mm
        self.retracted = False

    def travel(self, x: float, y: float) -> None:
        """Move to (x, y) without extruding, along the router's path; retract (and lift) when it says so."""
        if x == self.x and y == self.y:
            return
        if math.isnan(self.x):
            path, retract = np.asarray([[x, y]]), True
        elif self.router is not None:
            path, retract = self.router((self.x, self.y), (x, y))
            path = path[1:]
        else:
            path = np.asarray([[x, y]])
            retract = math.hypot(x - self.x, y - self.y) > self.p.retract_min_travel_mm
        lift = 0.0
        if retract:
            self._retract()
            lift = self.p.retract_lift_mm if self.retracted else 0.0
        if lift:
            self.out.append(f"G1 Z{self.z + lift:.3f} F{self._travel_f:.0f}")
        if not math.isnan(self.x):
            self.travel_mm += float(np.hypot(*np.diff(np.vstack([[self.x, self.y], path]), axis=0).T).sum())
        for px, py in path[:-1].tolist():
            self.out.append(f"G1 X{px:.3f} Y{py:.3f} F{self._travel_f:.0f}")
        self.out.append(f"G1 X{x:.3f} Y{y:.3f} F{self._travel_f:.0f}")
        if lift:
            self.out.append(f"G1 Z{self.z:.3f} F{self._travel_f:.0f}")
        self.x, self.y = x, y
        self.feed = self._travel_f

    def extrude(self, path: np.ndarray, kind: str, width_mm: float, height_mm: float,
                speed_mm_s: float, flow_r: float = 1.0, widths_mm: np.ndarray | None = None) -> None:
        """Extrude along a polyline ``path`` (m, 2) as a bead of the given width and height.

        ``flow_r`` scales the filament (bridge flow); ``widths_mm`` (m - 1), when
        given, is each segment's own bead width (gap fill), ``width_mm`` then
        only the one stated in the ``;WIDTH:`` comment.
        """
        if len(path) < 2:
            return
        self.travel(float(path[0, 0]), float(path[0, 1]))
        self._unretract()
        if kind != self.kind:
            self.out.append(f";TYPE:{kind}")
            self.kind = kind
        if width_mm != self.width:
            self.out.append(f";WIDTH:{width_mm:.4g}")
            self.width = width_mm
        feed = speed_mm_s * 60.0
        if feed != self.feed:
            self.out.append(f"G1 F{feed:.0f}")
            self.feed = feed
        d = path[1:] - path[:-1]
        if widths_mm is None:
            per_mm: float | np.ndarray = self._e_per_mm(width_mm, height_mm) * flow_r
        else:
            area = height_mm * (widths_mm - height_mm * (1.0 - math.pi / 4.0))     # bead_area_mm2, per segment
            per_mm = area * self.p.extrusion_multiplier_r * flow_r / self.p.filament_area_mm2
        e_mm = np.round(np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) * per_mm, 5)
        if len(e_mm) == 1:                                   # a lone line: skip the array machinery
            de = float(e_mm[0])
            if de > 0:
                self.out.append(f"G1 X{path[1, 0]:.3f} Y{path[1, 1]:.3f} E{de:.5f}")
            total = de
        else:
            keep = e_mm > 0
            pts = path[1:][keep].tolist()
            self.out += [f"G1 X{x:.3f} Y{y:.3f} E{de:.5f}"
                         for (x, y), de in zip(pts, e_mm[keep].tolist(), strict=True)]
            total = float(e_mm.sum())
        self.filament_mm += total
        self.net_filament_mm += total
        self.by_type[kind] = self.by_type.get(kind, 0.0) + total * self.p.filament_area_mm2
        self.x, self.y = float(path[-1, 0]), float(path[-1, 1])

    def _e_per_mm(self, width_mm: float, height_mm: float) -> float:
        """Filament per mm of path for a bead (memoised: a few widths and heights per print)."""
        key = (width_mm, height_mm)
        value = self._e_cache.get(key)
        if value is None:
            value = bead_area_mm2(width_mm, height_mm) * self.p.extrusion_multiplier_r / self.p.filament_area_mm2
            self._e_cache[key] = value
        return value

    def text(self) -> str:
        """The whole program, newline terminated."""
        return "\n".join(self.out) + "\n"
