"""The bead model: cross-section, spacing and filament length of an extruded line.

A bead of width ``w`` laid at layer height ``h`` is modelled, as in Slic3r and
PrusaSlicer, as a rectangle with semicircular ends: a ``(w - h) x h`` core plus
a circle of diameter ``h``::

    area = (w - h) * h + pi * (h / 2) ** 2 = h * (w - h * (1 - pi / 4))

Neighbouring beads are laid at the *spacing* ``s = area / h = w - h (1 - pi/4)``
so that the round flanks overlap just enough for the strip of beads to fill
``s * h`` of cross-section per bead with no gap and no excess. Filament (E, mm)
is the bead volume divided by the filament's cross-section.
"""
from __future__ import annotations

import math

__all__ = ["bead_area_mm2", "bead_spacing_mm", "width_for_spacing_mm", "filament_area_mm2"]

_ROUND = 1.0 - math.pi / 4.0


def bead_area_mm2(width_mm: float, height_mm: float) -> float:
    """Cross-section of a bead (mm^2): rectangle with semicircular flanks."""
    return height_mm * (width_mm - height_mm * _ROUND)


def bead_spacing_mm(width_mm: float, height_mm: float) -> float:
    """Centre-to-centre distance between touching beads (mm)."""
    return width_mm - height_mm * _ROUND


def width_for_spacing_mm(spacing_mm: float, height_mm: float) -> float:
    """The bead width that gives ``spacing_mm`` at ``height_mm`` (inverse of bead_spacing_mm)."""
    return spacing_mm + height_mm * _ROUND


def filament_area_mm2(filament_diameter_mm: float) -> float:
    """Cross-section of the raw filament (mm^2)."""
    return math.pi * (filament_diameter_mm / 2.0) ** 2
