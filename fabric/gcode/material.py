"""The material a G-code file states in its comments: filament diameter, material name, density, min temperature.

Slicers write their settings as comments, at the start (Cura's header, our
own built-in slicer, the start G-code of the external back-ends) or at the end
(PrusaSlicer's and Slic3r's configuration block, Cura's ``;SETTING_3``), so
only the first and last ``HEAD_BYTES`` of a file are read. Recognised::

    PrusaSlicer, Slic3r, am-fabric   ; filament_diameter = 2.85     ; filament_type = PLA
                                     ; filament_density = 1.24      ; min_extrude_temp_c = 170
    Cura                             ;Filament Diameter: 2.85   ;MATERIAL_DIAMETER:2.85
                                     ;EXTRUDER_TRAIN.0.MATERIAL.DIAMETER:2.85
                                     ;SETTING_3 ... material_diameter = 2.85 ... (split over lines)
    Simplify3D                       ;   filamentDiameters,2.85|2.85   ;   filamentDensities,1.25

A list (several extruders: ``2.85,2.85``, ``2.85|2.85``, ``PLA;PLA``) gives its
first value; a density of 0 (PrusaSlicer's "not set") is no statement. The
first statement found wins, the head before the tail. A stated value that is
not a number, or is out of range, is a
:class:`~fabric.wire.errors.GcodeError` naming the line.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

from fabric.wire.errors import GcodeError

__all__ = ["Material", "read_material", "header_lines", "HEAD_BYTES", "FILAMENT_DIAMETER_RANGE_MM",
           "DENSITY_RANGE_G_CM3", "MIN_EXTRUDE_TEMP_RANGE_C"]

HEAD_BYTES = 1 << 16                  # read at each end of a file
FILAMENT_DIAMETER_RANGE_MM = (0.5, 5.0)
DENSITY_RANGE_G_CM3 = (0.1, 25.0)
MIN_EXTRUDE_TEMP_RANGE_C = (0.0, 500.0)

_KEY = rb"^[ \t]*;[ \t]*(?P<key>%s)[ \t]*[:=,][ \t]*(?P<value>[^\r\n]*)"
_DIAMETER = re.compile(_KEY % rb"filament_diameter|filament diameter|material_diameter|filamentDiameters"
                       rb"|extruder_train\.0\.material\.diameter|filament_diameter_mm", re.I | re.M)
_NAME = re.compile(_KEY % rb"filament_type|material_type|material_name|material", re.I | re.M)
_DENSITY = re.compile(_KEY % rb"filament_density|filamentDensities|material_density|density_g_cm3", re.I | re.M)
_MIN_TEMP = re.compile(_KEY % rb"min_extrude_temp_c|min_extrude_temp", re.I | re.M)
_SETTING_3 = re.compile(rb"^;SETTING_3 ?([^\r\n]*)", re.M)
_CURA_DIAMETER = re.compile(rb"material_diameter\s*=\s*([^\s\\]+)")
_FIRST = re.compile(rb"[^,;|\s]+")


@dataclass(frozen=True)
class Material:
    """What a file (or a profile) states about its material; ``None``: not stated."""

    filament_diameter_mm: float | None = None
    material: str | None = None
    density_g_cm3: float | None = None
    min_extrude_temp_c: float | None = None

    def meta(self) -> dict[str, float | str]:
        """The stated values under the program-meta keys (absent ones left out)."""
        return {k: v for k, v in (("filament_diameter_mm", self.filament_diameter_mm), ("material", self.material),
                                  ("density_g_cm3", self.density_g_cm3),
                                  ("min_extrude_temp_c", self.min_extrude_temp_c)) if v is not None}


def header_lines(filament_diameter_mm: float, material: str, density_g_cm3: float,
                 min_extrude_temp_c: float) -> list[str]:
    """What a slicer writes as comments (after ``; ``) so the file carries its material (PrusaSlicer's keys,
    and ours for the minimum temperature)."""
    return [f"filament_diameter = {filament_diameter_mm:g}", f"filament_type = {material}",
            f"filament_density = {density_g_cm3:g}", f"min_extrude_temp_c = {min_extrude_temp_c:g}"]


class _Region:
    """A head or tail of the file and the 1-based number of its first line (0: unknown)."""

    def __init__(self, data: bytes, first_line: int) -> None:
        self.data, self.first_line = data, first_line

    def line_of(self, pos: int) -> int:
        return self.first_line + self.data.count(b"\n", 0, pos) if self.first_line else 0


def read_material(head: bytes, tail: bytes = b"", n_lines: int = 0) -> Material:
    """The material stated in the first bytes ``head`` and the last bytes ``tail`` of a file.

    ``tail`` must not overlap ``head`` (pass ``b""`` for a file read whole in
    ``head``); ``n_lines`` (the file's line count) lets errors in the tail name their line.
    """
    tail_first = n_lines - tail.count(b"\n") + (1 if tail.endswith(b"\n") else 0) if n_lines and tail else 0
    regions = [_Region(head, 1), _Region(tail, max(tail_first, 0))]
    diameter = _number(regions, _DIAMETER, "filament diameter", FILAMENT_DIAMETER_RANGE_MM)
    if diameter is None:
        diameter = _cura_setting(regions)
    return Material(filament_diameter_mm=diameter, material=_text(regions, _NAME),
                    density_g_cm3=_number(regions, _DENSITY, "filament density", DENSITY_RANGE_G_CM3),
                    min_extrude_temp_c=_number(regions, _MIN_TEMP, "minimum extrusion temperature",
                                               MIN_EXTRUDE_TEMP_RANGE_C))


def _first_match(regions: list[_Region], pattern: re.Pattern[bytes]) -> tuple[_Region, re.Match[bytes]] | None:
    for region in regions:
        m = pattern.search(region.data)
        if m is not None:
            return region, m
    return None


def _first_value(raw: bytes) -> bytes:
    m = _FIRST.search(raw)
    return m.group(0) if m else b""


def _number(regions: list[_Region], pattern: re.Pattern[bytes], what: str,
            bounds: tuple[float, float]) -> float | None:
    found = _first_match(regions, pattern)
    if found is None:
        return None
    region, m = found
    text = m.group(0).decode("utf-8", "replace").strip()
    raw = _first_value(m.group("value"))
    if pattern is _DENSITY and _is_zero(raw):
        return None                     # PrusaSlicer and Slic3r write a density of 0 for "not set"
    return _checked(raw, what, bounds, region.line_of(m.start("key")), text)


def _is_zero(raw: bytes) -> bool:
    try:
        return float(raw) == 0.0
    except ValueError:
        return False


def _checked(raw: bytes, what: str, bounds: tuple[float, float], line: int, text: str) -> float:
    lo, hi = bounds
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not (lo <= value <= hi):
        message = (f"the stated {what} {raw.decode('utf-8', 'replace')!r} is not a number in [{lo:g}, {hi:g}]: "
                   f"{text!r}")
        if not line:
            raise GcodeError(f"near the end of the file: {message}", text=text[:200])
        raise GcodeError(message, line=line, text=text[:200])
    return value


def _text(regions: list[_Region], pattern: re.Pattern[bytes]) -> str | None:
    found = _first_match(regions, pattern)
    if found is None:
        return None
    value = _first_value(found[1].group("value")).decode("utf-8", "replace").strip().strip('"')
    return value[:64] or None


def _cura_setting(regions: list[_Region]) -> float | None:
    """Cura's ``material_diameter`` inside its ``;SETTING_3`` lines (one JSON string cut into lines)."""
    for region in regions:
        lines = list(_SETTING_3.finditer(region.data))
        if not lines:
            continue
        m = _CURA_DIAMETER.search(b"".join(line.group(1) for line in lines))
        if m is not None:
            text = "SETTING_3 material_diameter = " + m.group(1).decode("utf-8", "replace")
            return _checked(m.group(1), "filament diameter", FILAMENT_DIAMETER_RANGE_MM,
                            region.line_of(lines[0].start()), text)
    return None
