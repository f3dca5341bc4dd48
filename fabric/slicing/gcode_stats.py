"""Read back what a slicer produced: layers, extruded volume and filament, per feature type.

All back-ends write relative E (M83) in mm of filament, layer markers
(``;LAYER_CHANGE`` then ``;Z:<mm>``) and feature markers (``;TYPE:<name>``),
so one reader measures them all. *Extruded volume* counts only E on moves
that also travel in XY (deposited beads): a retraction and its matching
de-retraction are E-only moves and cancel, so they are left out. Absolute E
(M82) is understood too, by differencing.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

__all__ = ["GcodeStats", "gcode_stats"]

_WORD = re.compile(r"([XYZEF])\s*(-?\d*\.?\d+(?:[eE][-+]?\d+)?)")
# relative-E fast path: the E of every G0/G1 line, and of the lines that only move E
_E_ANY = re.compile(r"^G[01] [^;\nE]*E(-?\d*\.?\d+)", re.MULTILINE)
_E_ONLY = re.compile(r"^G[01] E(-?\d*\.?\d+)", re.MULTILINE)
_Z = re.compile(r"^;Z:(-?[\d.]+)", re.MULTILINE)


@dataclass
class GcodeStats:
    """Totals of one G-code text (mm, mm^3)."""

    layers: int
    extruded_filament_mm: float           # E on extruding XY moves
    net_filament_mm: float                # all E, retractions included
    extruded_mm3: float
    volume_by_type_mm3: dict[str, float] = field(default_factory=dict)
    layer_z_mm: list[float] = field(default_factory=list)


def gcode_stats(gcode: str, filament_diameter_mm: float) -> GcodeStats:
    """Measure ``gcode`` (a whole file as text) with the given filament diameter."""
    if re.search(r"^M82\b", gcode, re.MULTILINE) is None:
        return _relative_stats(gcode, filament_diameter_mm)
    return _general_stats(gcode, filament_diameter_mm)


def _relative_stats(gcode: str, filament_diameter_mm: float) -> GcodeStats:
    """Relative E throughout (the fabric's convention): regular expressions over whole sections.

    Beads are the positive E of moves that are not E-only (retractions and
    de-retractions are written as ``G1 E... F...``, Z moves carry no E).
    """
    area = np.pi * (filament_diameter_mm / 2.0) ** 2
    by_type: dict[str, float] = {}
    total = 0.0
    sections = gcode.split("\n;TYPE:")
    for n, section in enumerate(sections):
        kind = "Unknown" if n == 0 else section[:section.find("\n")].strip()
        e = np.asarray(_E_ANY.findall(section), dtype=np.float64)
        e_only = np.asarray(_E_ONLY.findall(section), dtype=np.float64)
        pos = float(e[e > 0].sum() - e_only[e_only > 0].sum())
        if pos:
            by_type[kind] = by_type.get(kind, 0.0) + pos * area
            total += pos
    net = float(np.asarray(_E_ANY.findall(gcode), dtype=np.float64).sum())
    layer_z = [float(z) for z in _Z.findall(gcode)]
    return GcodeStats(layers=len(layer_z), extruded_filament_mm=total, net_filament_mm=net,
                      extruded_mm3=total * area, volume_by_type_mm3=by_type, layer_z_mm=layer_z)


def _general_stats(gcode: str, filament_diameter_mm: float) -> GcodeStats:
    """Line by line, following M82 / M83 and G92 E resets."""
    area = np.pi * (filament_diameter_mm / 2.0) ** 2
    relative = True
    last_e = 0.0
    x = y = None
    kind = "Unknown"
    by_type: dict[str, float] = {}
    total_xy = 0.0
    net = 0.0
    layer_z: list[float] = []
    for line in gcode.splitlines():
        if not line:
            continue
        c = line[0]
        if c == ";":
            if line.startswith(";TYPE:"):
                kind = line[6:].strip()
            elif line.startswith(";Z:"):
                layer_z.append(float(line[3:]))
            continue
        if c == "M":
            if line.startswith("M83"):
                relative = True
            elif line.startswith("M82"):
                relative = False
            continue
        if c != "G":
            continue
        if line.startswith("G92"):
            m = re.search(r"E\s*(-?\d*\.?\d+)", line)
            if m:
                last_e = float(m.group(1))
            continue
        if not (line.startswith("G1") or line.startswith("G0")):
            continue
        words = dict(_WORD.findall(line.split(";", 1)[0][2:]))
        moved = False
        if "X" in words and float(words["X"]) != x:
            x, moved = float(words["X"]), True
        if "Y" in words and float(words["Y"]) != y:
            y, moved = float(words["Y"]), True
        if "E" in words:
            e = float(words["E"])
            de = e if relative else e - last_e
            last_e = e if not relative else last_e
            net += de
            if moved and de > 0:
                total_xy += de
                by_type[kind] = by_type.get(kind, 0.0) + de * area
    return GcodeStats(layers=len(layer_z), extruded_filament_mm=total_xy, net_filament_mm=net,
                      extruded_mm3=total_xy * area, volume_by_type_mm3=by_type, layer_z_mm=layer_z)
