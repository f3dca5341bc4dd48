"""Slicing profiles: one typed, range-checked schema shared by every slicer back-end.

A profile is a TOML file of flat ``key = value`` pairs whose keys are exactly the
fields of :class:`Profile` (units in the names). Shipped profiles live in
``fabric/slicing/profiles/``; a path to any other TOML file works too. Unknown
keys and out-of-range values are a :class:`ProfileError` naming the key and the
file, so a typo never silently falls back to a default.
"""
from __future__ import annotations

import dataclasses
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib

from fabric.wire.errors import NotFound, ProfileError

__all__ = ["Profile", "load_profile", "list_profiles", "PROFILE_DIR"]

PROFILE_DIR = Path(__file__).with_name("profiles")

INFILL_PATTERNS = ("rectilinear", "grid")
SEAMS = ("aligned", "nearest")


@dataclass(frozen=True)
class Profile:
    """Everything a back-end needs to turn a placed mesh into G-code (mm, s, deg C).

    Widths and heights describe the bead: ``extrusion_width_mm`` is the bead's
    width, every layer but the first is ``layer_height_mm`` thick. Speeds are
    TCP speeds along the path. ``infill_density_r`` is the sparse infill's
    volume fraction (0..1); solid layers are always 100 %. Bridges (solid
    infill over air or over sparse infill) print at ``bridge_speed_mm_s`` with
    ``bridge_flow_r`` times the normal flow. A travel retracts when it is longer
    than ``retract_min_travel_mm`` and leaves the part (crosses a perimeter into
    open air), or when its route inside the part is longer than
    ``retract_inside_max_mm``. The material
    (``filament_diameter_mm``, ``material``, ``density_g_cm3``,
    ``min_extrude_temp_c``) is written into the G-code's header, from where the
    planner and the twin read it.
    """

    name: str = "custom"
    layer_height_mm: float = 0.25
    first_layer_height_mm: float = 0.3
    nozzle_diameter_mm: float = 0.35
    filament_diameter_mm: float = 2.85
    material: str = "PLA"
    density_g_cm3: float = 1.24
    min_extrude_temp_c: float = 170.0
    extrusion_width_mm: float = 0.42
    extrusion_multiplier_r: float = 1.0
    perimeters: int = 2
    top_solid_layers: int = 4
    bottom_solid_layers: int = 3
    infill_density_r: float = 0.2
    infill_pattern: str = "rectilinear"
    infill_angle_deg: float = 45.0
    infill_overlap_r: float = 0.25
    perimeter_speed_mm_s: float = 40.0
    infill_speed_mm_s: float = 60.0
    solid_infill_speed_mm_s: float = 40.0
    bridge_speed_mm_s: float = 25.0
    bridge_flow_r: float = 1.0
    travel_speed_mm_s: float = 150.0
    first_layer_speed_mm_s: float = 20.0
    nozzle_temp_c: float = 205.0
    bed_temp_c: float = 60.0
    retract_length_mm: float = 1.0
    retract_speed_mm_s: float = 25.0
    retract_lift_mm: float = 0.0
    retract_min_travel_mm: float = 2.0
    retract_inside_max_mm: float = 50.0
    seam: str = "aligned"
    skirt_loops: int = 0
    skirt_distance_mm: float = 6.0

    def __post_init__(self) -> None:
        _validate(self, source=self.name)

    @property
    def filament_area_mm2(self) -> float:
        """Cross-section of the raw filament: E (mm) times this is extruded mm^3."""
        return math.pi * (self.filament_diameter_mm / 2.0) ** 2

    def material_header(self) -> list[str]:
        """The G-code comments (without ``; ``) stating this profile's material."""
        from fabric.gcode.material import header_lines
        return header_lines(self.filament_diameter_mm, self.material, self.density_g_cm3, self.min_extrude_temp_c)

    def replace(self, **changes: Any) -> Profile:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


_FIELDS = {f.name: f for f in dataclasses.fields(Profile)}
# (min, max) inclusive ranges; None = unbounded on that side.
_RANGES: dict[str, tuple[float | None, float | None]] = {
    "layer_height_mm": (0.01, 5.0), "first_layer_height_mm": (0.01, 5.0),
    "nozzle_diameter_mm": (0.05, 5.0), "filament_diameter_mm": (0.5, 5.0),
    "density_g_cm3": (0.1, 25.0), "min_extrude_temp_c": (0.0, 500.0),
    "extrusion_width_mm": (0.05, 10.0), "extrusion_multiplier_r": (0.1, 3.0),
    "perimeters": (0, 50), "top_solid_layers": (0, 100), "bottom_solid_layers": (0, 100),
    "infill_density_r": (0.0, 1.0), "infill_angle_deg": (-360.0, 360.0),
    "infill_overlap_r": (0.0, 1.0),
    "perimeter_speed_mm_s": (0.1, 1000.0), "infill_speed_mm_s": (0.1, 1000.0),
    "solid_infill_speed_mm_s": (0.1, 1000.0), "travel_speed_mm_s": (0.1, 2000.0),
    "bridge_speed_mm_s": (0.1, 1000.0), "bridge_flow_r": (0.1, 3.0), "retract_inside_max_mm": (0.0, 10000.0),
    "first_layer_speed_mm_s": (0.1, 1000.0),
    "nozzle_temp_c": (0.0, 500.0), "bed_temp_c": (0.0, 200.0),
    "retract_length_mm": (0.0, 50.0), "retract_speed_mm_s": (0.1, 500.0),
    "retract_lift_mm": (0.0, 20.0), "retract_min_travel_mm": (0.0, 1000.0),
    "skirt_loops": (0, 50), "skirt_distance_mm": (0.0, 100.0),
}
_MATERIAL_NAME = re.compile(r"[A-Za-z0-9_+-]{1,32}")     # one word: it goes into G-code comments
_CHOICES = {"infill_pattern": INFILL_PATTERNS, "seam": SEAMS}


def _validate(p: Profile, source: str) -> None:
    """Range and consistency checks; raise ProfileError naming the key."""
    for key, field in _FIELDS.items():
        value = getattr(p, key)
        want = field.type
        if want == "int" and (isinstance(value, bool) or not isinstance(value, int)):
            raise ProfileError(f"{source}: {key} must be an integer, got {value!r}", key=key, value=repr(value))
        if want == "float" and (isinstance(value, bool) or not isinstance(value, (int, float))
                                or not math.isfinite(value)):
            raise ProfileError(f"{source}: {key} must be a number, got {value!r}", key=key, value=repr(value))
        if want == "str" and not isinstance(value, str):
            raise ProfileError(f"{source}: {key} must be a string, got {value!r}", key=key, value=repr(value))
        lo, hi = _RANGES.get(key, (None, None))
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise ProfileError(f"{source}: {key} = {value} is out of range [{lo}, {hi}]",
                               key=key, value=value, min=lo, max=hi)
        if key == "material" and not _MATERIAL_NAME.fullmatch(value):
            raise ProfileError(f"{source}: material = {value!r} must be 1-32 letters, digits, '-', '_' or '+'",
                               key=key, value=value)
        if key in _CHOICES and value not in _CHOICES[key]:
            raise ProfileError(f"{source}: {key} = {value!r} is not one of {', '.join(_CHOICES[key])}",
                               key=key, value=value, choices=list(_CHOICES[key]))
    # The bead model (a rectangle with round ends) needs a bead wider than it is tall.
    for hkey in ("layer_height_mm", "first_layer_height_mm"):
        h = getattr(p, hkey)
        if h > p.nozzle_diameter_mm:
            raise ProfileError(f"{source}: {hkey} = {h} exceeds nozzle_diameter_mm = {p.nozzle_diameter_mm}",
                               key=hkey, value=h, limit=p.nozzle_diameter_mm)
        if p.extrusion_width_mm <= h:
            raise ProfileError(f"{source}: extrusion_width_mm = {p.extrusion_width_mm} must exceed {hkey} = {h}",
                               key="extrusion_width_mm", value=p.extrusion_width_mm, limit=h)


def _coerce(key: str, raw: Any, source: str) -> Any:
    """Convert a TOML value or an override string to the field's type."""
    if key not in _FIELDS:
        raise ProfileError(f"{source}: unknown profile key {key!r}", key=key,
                           known=sorted(_FIELDS))
    want = _FIELDS[key].type
    if not isinstance(raw, str) or want == "str":
        if want == "float" and isinstance(raw, int) and not isinstance(raw, bool):
            return float(raw)
        return raw
    text = raw.strip()
    try:
        if want == "int":
            return int(text)
        if want == "float":
            if text.endswith("%") and key.endswith("_r"):
                return float(text[:-1]) / 100.0
            return float(text)
    except ValueError:
        raise ProfileError(f"{source}: {key} = {raw!r} is not a valid {want}", key=key, value=raw) from None
    return text


def list_profiles() -> list[str]:
    """Names of the profiles shipped with the package, sorted."""
    return sorted(p.stem for p in PROFILE_DIR.glob("*.toml"))


def load_profile(name_or_path: str, overrides: dict[str, str] | None = None) -> Profile:
    """Load a shipped profile by name (or a TOML file by path) and apply ``key=value`` overrides.

    Override values are strings parsed to the field's type (``"0.3"``,
    ``"3"``, ``"grid"``; ratios also accept ``"20%"``).
    """
    path = PROFILE_DIR / f"{name_or_path}.toml"
    if not path.is_file():
        candidate = Path(name_or_path)
        if candidate.suffix == ".toml" and candidate.is_file():
            path = candidate
        else:
            raise NotFound(f"unknown profile {name_or_path!r} (shipped: {', '.join(list_profiles())})",
                           profile=name_or_path, known=list_profiles())
    source = str(path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ProfileError(f"{source}: not valid TOML: {exc}", file=source) from exc
    values: dict[str, Any] = {"name": path.stem}
    for key, value in raw.items():
        values[key] = _coerce(key, value, source)
    for key, value in (overrides or {}).items():
        values[key] = _coerce(key, value, "override")
    try:
        return Profile(**values)
    except ProfileError as exc:
        exc.details.setdefault("file", source)
        raise
