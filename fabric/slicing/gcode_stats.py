"""Read back what a slicer produced: layers, extruded volume and filament per feature type, retractions, travel.

All back-ends write relative E (M83) in mm of filament, layer markers
(``;LAYER_CHANGE`` then ``;Z:<mm>``) and feature markers (``;TYPE:<name>``),
so one reader measures them all. *Extruded volume* counts only E on moves
that also travel in XY (deposited beads): a retraction and its matching
de-retraction are E-only moves and cancel, so they are left out. Absolute E
(M82) is understood too, by differencing. A *retraction* is an E-only move
that pulls filament back (every stop the nozzle makes to travel without
oozing); *travel* is the XY length of the moves that do not extrude.
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
# XY moves as the slicers write them (words in the order X Y [Z] [E]); travel is every XY move without +E
_XY = re.compile(r"^G[01](?: X(-?\d*\.?\d+))?(?: Y(-?\d*\.?\d+))?(?: Z-?\d*\.?\d+)?(?: E(-?\d*\.?\d+))?",
                 re.MULTILINE)


@dataclass
class GcodeStats:
    """Totals of one G-code text (mm, mm^3)."""

    layers: int
    extruded_filament_mm: float           # E on extruding XY moves
    net_filament_mm: float                # all E, retractions included
    extruded_mm3: float
    volume_by_type_mm3: dict[str, float] = field(default_factory=dict)
    layer_z_mm: list[float] = field(default_factory=list)
    retractions: int = 0                  # E-only moves pulling filament back
    travel_mm: float = 0.0                # XY length of the moves that do not extrude


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
    retractions = int((np.asarray(_E_ONLY.findall(gcode), dtype=np.float64) < 0).sum())
    return GcodeStats(layers=len(layer_z), extruded_filament_mm=total, net_filament_mm=net,
                      extruded_mm3=total * area, volume_by_type_mm3=by_type, layer_z_mm=layer_z,
                      retractions=retractions, travel_mm=_travel_mm(gcode))


def _travel_mm(gcode: str) -> float:
    """XY length of the non-extruding moves (relative E), from one pass of a regular expression."""
    rows = [(x, y, e) for x, y, e in _XY.findall(gcode) if x or y]
    if len(rows) < 2:
        return 0.0
    nan = float("nan")
    xy = np.asarray([(float(x) if x else nan, float(y) if y else nan) for x, y, _ in rows])
    for col in (0, 1):                       # a word left out keeps its previous value
        v = xy[:, col]
        idx = np.where(np.isnan(v), 0, np.arange(len(v)))
        np.maximum.accumulate(idx, out=idx)
        xy[:, col] = v[idx]
    extruding = np.asarray([bool(e) and float(e) > 0 for _, _, e in rows])
    step = np.hypot(*np.diff(xy, axis=0).T)
    return float(np.nansum(step[~extruding[1:]]))


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
    retractions = 0
    travel = 0.0
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
        x0, y0 = x, y
        if "X" in words and float(words["X"]) != x:
            x, moved = float(words["X"]), True
        if "Y" in words and float(words["Y"]) != y:
            y, moved = float(words["Y"]), True
        de = 0.0
        if "E" in words:
            e = float(words["E"])
            de = e if relative else e - last_e
            last_e = e if not relative else last_e
            net += de
            if moved and de > 0:
                total_xy += de
                by_type[kind] = by_type.get(kind, 0.0) + de * area
            elif not moved and de < 0:
                retractions += 1
        if moved and de <= 0 and x0 is not None and y0 is not None and x is not None and y is not None:
            travel += ((x - x0) ** 2 + (y - y0) ** 2) ** 0.5
    return GcodeStats(layers=len(layer_z), extruded_filament_mm=total_xy, net_filament_mm=net,
                      extruded_mm3=total_xy * area, volume_by_type_mm3=by_type, layer_z_mm=layer_z,
                      retractions=retractions, travel_mm=travel)
