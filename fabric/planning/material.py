"""Which material a plan uses: the user's option, else what the G-code states, else an assumption it says aloud.

The filament diameter turns E (mm of filament) into volume, so a wrong one
scales every volume by the ratio of the areas (1.75 mm assumed for 2.85 mm
filament: 2.65 times too little). The planner takes, in this order:

1. ``PlanOptions.filament_diameter_mm`` (``fabric-cli plan --filament-diameter``,
   ``PlanRequest.filament_diameter_mm``), the user's explicit word;
2. what the G-code's comments state (:mod:`fabric.gcode.material`: our
   slicers write the profile's material there; PrusaSlicer, Slic3r, Cura and
   Simplify3D state the diameter in their own way);
3. ``ASSUMED_FILAMENT_DIAMETER_MM``, with a warning in the plan.

The name, density and minimum extrusion temperature come from the G-code
when it states them (the option gives only the diameter).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from fabric.gcode.material import Material
from fabric.schemas.pipeline import MATERIAL_SOURCES

__all__ = ["ResolvedMaterial", "resolve_material", "ASSUMED_FILAMENT_DIAMETER_MM", "MATERIAL_SOURCES"]

ASSUMED_FILAMENT_DIAMETER_MM = 1.75


@dataclass(frozen=True)
class ResolvedMaterial:
    """The material of a plan; ``source`` says where the filament diameter came from."""

    filament_diameter_mm: float
    source: str
    material: str | None = None
    density_g_cm3: float | None = None
    min_extrude_temp_c: float | None = None
    warnings: list[str] = field(default_factory=list)

    def meta(self) -> dict[str, Any]:
        """Program-meta entries (``filament_diameter_mm`` always; the others when known)."""
        stated = Material(self.filament_diameter_mm, self.material, self.density_g_cm3, self.min_extrude_temp_c)
        return {**stated.meta(), "material_source": self.source}


def resolve_material(stated: Material, option_diameter_mm: float | None) -> ResolvedMaterial:
    """The plan's material from the user's option and what the G-code states (see the module docstring)."""
    warnings: list[str] = []
    said = stated.filament_diameter_mm
    if option_diameter_mm is not None:
        diameter, source = float(option_diameter_mm), "option"
        if said is not None and abs(said - diameter) > 1e-6:
            warnings.append(f"filament diameter {diameter:g} mm as asked, although the G-code states {said:g} mm")
    elif said is not None:
        diameter, source = float(said), "gcode"
    else:
        diameter, source = ASSUMED_FILAMENT_DIAMETER_MM, "assumed"
        warnings.append(f"the G-code states no filament diameter: assumed {diameter:g} mm "
                        "(give the right one with --filament-diameter; volumes scale with its square)")
    return ResolvedMaterial(filament_diameter_mm=diameter, source=source, material=stated.material,
                            density_g_cm3=stated.density_g_cm3, min_extrude_temp_c=stated.min_extrude_temp_c,
                            warnings=warnings)
