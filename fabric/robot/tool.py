"""The extruder tool's collision envelope: its body, its nozzle and, for a tapered nozzle, the cone's cover.

Pure geometry (no Pinocchio): the robot model hangs it from the flange
(:mod:`fabric.robot.model`), the curved slicer looks along the same cover when it
turns a nozzle clear of the beads (:mod:`fabric.slicing.curved.reach`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabric.wire.errors import ConfigError

__all__ = ["ToolGeometry", "taper_cover", "TAPER_STEPS", "TAPER_LINK"]

TAPER_STEPS = 3                 # cylinders covering a tapered nozzle's cone
TAPER_LINK = "tool_taper"       # their links: tool_taper1 (at the tip) .. tool_taper3


@dataclass(frozen=True)
class ToolGeometry:
    """Collision envelope of the extruder tool (mm).

    The body is a cylinder from the flange along its z axis; the nozzle is a
    cylinder along the TCP z axis that stops ``nozzle_clearance_mm`` short of
    the tip.

    A tapered nozzle (``taper_length_mm`` > 0) ends in a flat of
    ``tip_diameter_mm`` across: from the tip up, the flat's cylinder
    (``nozzle_clearance_mm`` long, the tip that lays the bead), then a cone
    widening to ``nozzle_diameter_mm`` over ``taper_length_mm``, then the
    nozzle's cylinder. The cone is covered by ``TAPER_STEPS`` cylinders, each as
    wide as the cone at its top (:meth:`taper_steps`): nothing of the cone
    lies outside them. Real nozzles are cones: a slender one reaches into a
    crease of the part (the crown of an arch, where layers from both sides
    meet) where a cylinder as wide as its shank would not.
    """

    body_diameter_mm: float = 60.0
    body_length_mm: float = 120.0
    nozzle_diameter_mm: float = 8.0
    nozzle_length_mm: float = 29.0
    nozzle_clearance_mm: float = 1.0
    tip_diameter_mm: float = 0.0        # the flat at the tip; 0: the nozzle's diameter (no taper)
    taper_length_mm: float = 0.0        # the cone from the tip's flat to the nozzle's diameter; 0: none

    OPTIONAL = ("tip_diameter_mm", "taper_length_mm")   # may be 0

    def check(self) -> None:
        """Raise ConfigError naming the first dimension out of range."""
        for name, value in vars(self).items():
            low_ok = value >= 0.0 if name in self.OPTIONAL else value > 0.0
            if not (np.isfinite(value) and low_ok):
                bound = ">= 0" if name in self.OPTIONAL else "> 0"
                raise ConfigError(f"tool.{name} must be {bound}, got {value}", field=f"tool.{name}", value=value)
        if self.tip_diameter_mm > self.nozzle_diameter_mm:
            raise ConfigError(f"tool.tip_diameter_mm {self.tip_diameter_mm:g} is wider than the nozzle "
                              f"({self.nozzle_diameter_mm:g} mm)", field="tool.tip_diameter_mm",
                              value=self.tip_diameter_mm)
        if (self.taper_length_mm > 0.0) != (0.0 < self.tip_diameter_mm < self.nozzle_diameter_mm):
            raise ConfigError("a tapered nozzle needs both tool.tip_diameter_mm (narrower than the nozzle) and "
                              "tool.taper_length_mm", field="tool.taper_length_mm", value=self.taper_length_mm)

    @property
    def tip_mm(self) -> float:
        """The diameter of the nozzle's tip (its flat)."""
        return self.tip_diameter_mm if self.taper_length_mm > 0.0 else self.nozzle_diameter_mm

    def taper_steps(self) -> list[tuple[float, float, float]]:
        """The cylinders covering the cone: (radius, length, start above the tip), mm; none untapered."""
        if self.taper_length_mm <= 0.0:
            return []
        return taper_cover(self.tip_diameter_mm / 2.0, self.nozzle_diameter_mm / 2.0, self.taper_length_mm,
                           self.nozzle_clearance_mm)



def taper_cover(tip_radius_mm: float, radius_mm: float, length_mm: float, start_mm: float
                ) -> list[tuple[float, float, float]]:
    """``TAPER_STEPS`` cylinders covering a cone from ``tip_radius_mm`` to ``radius_mm`` over ``length_mm``,
    beginning ``start_mm`` above the tip: (radius, length, start), each as wide as the cone at its top."""
    step = length_mm / TAPER_STEPS
    return [(tip_radius_mm + (radius_mm - tip_radius_mm) * (k + 1) / TAPER_STEPS, step, start_mm + k * step)
            for k in range(TAPER_STEPS)]
