"""PrusaSlicer 2.5 and Slic3r 1.3 as slicing back-ends, configured from the same Profile.

Each back-end gets the *placed* mesh (bed coordinates, written as binary STL
into a temporary directory) and ``--dont-arrange``, so the part lands where
the Placement put it, plus an ini file generated from the profile. The ini
makes both produce the fabric's conventions: relative E (M83) in mm of
filament, a start that only sets temperatures (no G28), ``;LAYER_CHANGE`` /
``;Z:`` markers and ``;TYPE:`` features. Features that differ between
slicers are switched off or matched to the built-in slicer (classic
perimeters, gap fill on and thin walls / ironing / extra perimeters off, no
infill anchors, rectilinear top and bottom, same widths everywhere, same
overlap, thin bridges with the profile's bridge flow and speed), so volumes
are comparable. Travel follows the built-in slicer's rule too: avoid
crossing perimeters, retract only when a travel crosses them, no retraction
just for a layer change (PrusaSlicer has no limit on an inside travel's
length, so ``retract_inside_max_mm`` has no counterpart there).

Slic3r 1.3 has no ``;TYPE:`` comments; with ``gcode_comments`` it tags each
move (``; perimeter``, ``; infill``, ``; skirt``), which is turned into
``;TYPE:Perimeter`` / ``Infill`` / ``Skirt/Brim`` (it does not tell external
perimeters or solid infill apart).
"""
from __future__ import annotations

import functools
import re
import shutil
import subprocess
import tempfile
from collections.abc import Callable
from pathlib import Path

import trimesh

from fabric.slicing.profile import Profile
from fabric.wire.errors import NotFound, SlicerError

__all__ = ["EXTERNAL", "external_version", "run_external", "prusaslicer_ini", "slic3r_ini"]

TIMEOUT_S = 900.0
_STDERR_LINES = 12


def _gcode_block(lines: list[str]) -> str:
    return "\\n".join(lines) + "\\n"


def _start_end(p: Profile) -> tuple[str, str]:
    material = [f"; {line}" for line in p.material_header()]       # the planner and the twin read these
    start = material + [f"M140 S{p.bed_temp_c:g}", f"M104 S{p.nozzle_temp_c:g}", f"M190 S{p.bed_temp_c:g}",
                        f"M109 S{p.nozzle_temp_c:g}", "M83", "G92 E0"]
    return _gcode_block(start), _gcode_block(["M104 S0", "M140 S0"])


def _common(p: Profile, plate_size_mm: tuple[float, float]) -> dict[str, str]:
    """Options both slicers understand with the same meaning."""
    w, h = plate_size_mm
    start, end = _start_end(p)
    width = f"{p.extrusion_width_mm:g}"
    return {
        "bed_shape": f"0x0,{w:g}x0,{w:g}x{h:g},0x{h:g}",
        "layer_height": f"{p.layer_height_mm:g}", "first_layer_height": f"{p.first_layer_height_mm:g}",
        "nozzle_diameter": f"{p.nozzle_diameter_mm:g}", "filament_diameter": f"{p.filament_diameter_mm:g}",
        "extrusion_multiplier": f"{p.extrusion_multiplier_r:g}",
        **{key: width for key in ("extrusion_width", "first_layer_extrusion_width",
                                  "perimeter_extrusion_width", "external_perimeter_extrusion_width",
                                  "infill_extrusion_width", "solid_infill_extrusion_width",
                                  "top_infill_extrusion_width")},
        "perimeters": str(p.perimeters), "top_solid_layers": str(p.top_solid_layers),
        "bottom_solid_layers": str(p.bottom_solid_layers),
        "fill_density": f"{p.infill_density_r * 100:g}%", "fill_pattern": p.infill_pattern,
        "fill_angle": f"{p.infill_angle_deg:g}", "infill_overlap": f"{p.infill_overlap_r * 100:g}%",
        "solid_infill_below_area": "0", "thin_walls": "0", "extra_perimeters": "0",
        "infill_every_layers": "1", "infill_only_where_needed": "0", "infill_first": "0",
        "external_perimeters_first": "0", "seam_position": p.seam,
        "skirts": str(p.skirt_loops), "skirt_distance": f"{p.skirt_distance_mm:g}", "skirt_height": "1",
        "min_skirt_length": "0", "brim_width": "0",
        "perimeter_speed": f"{p.perimeter_speed_mm_s:g}",
        "external_perimeter_speed": f"{p.perimeter_speed_mm_s:g}",
        "small_perimeter_speed": f"{p.perimeter_speed_mm_s:g}",
        "infill_speed": f"{p.infill_speed_mm_s:g}", "solid_infill_speed": f"{p.solid_infill_speed_mm_s:g}",
        "top_solid_infill_speed": f"{p.solid_infill_speed_mm_s:g}",
        "bridge_speed": f"{p.bridge_speed_mm_s:g}", "gap_fill_speed": f"{p.solid_infill_speed_mm_s:g}",
        "first_layer_speed": f"{p.first_layer_speed_mm_s:g}", "travel_speed": f"{p.travel_speed_mm_s:g}",
        "retract_length": f"{p.retract_length_mm:g}", "retract_speed": f"{p.retract_speed_mm_s:g}",
        "retract_lift": f"{p.retract_lift_mm:g}", "retract_before_travel": f"{p.retract_min_travel_mm:g}",
        "retract_layer_change": "0", "wipe": "0",
        "temperature": f"{p.nozzle_temp_c:g}", "first_layer_temperature": f"{p.nozzle_temp_c:g}",
        "bed_temperature": f"{p.bed_temp_c:g}", "first_layer_bed_temperature": f"{p.bed_temp_c:g}",
        "cooling": "0", "fan_always_on": "0", "use_relative_e_distances": "1",
        "start_gcode": start, "end_gcode": end, "complete_objects": "0",
        "avoid_crossing_perimeters": "1", "only_retract_when_crossing_perimeters": "1", "xy_size_compensation": "0",
        "bridge_flow_ratio": f"{p.bridge_flow_r:g}",
    }


def prusaslicer_ini(p: Profile, plate_size_mm: tuple[float, float], build_height_mm: float) -> dict[str, str]:
    """PrusaSlicer 2.5 options for ``p`` (see module docstring for what is switched off)."""
    out = _common(p, plate_size_mm)
    out.update({
        "max_print_height": f"{build_height_mm:g}", "perimeter_generator": "classic",
        "top_fill_pattern": "rectilinear", "bottom_fill_pattern": "rectilinear",
        "infill_anchor": "0", "infill_anchor_max": "0", "gap_fill_enabled": "1",
        "avoid_crossing_perimeters_max_detour": "0",
        "ensure_vertical_shell_thickness": "0", "thick_bridges": "0", "overhangs": "0",
        "ironing": "0", "elefant_foot_compensation": "0", "top_solid_min_thickness": "0",
        "bottom_solid_min_thickness": "0", "gcode_comments": "0", "gcode_label_objects": "0",
        "remaining_times": "0", "fuzzy_skin": "none", "raft_layers": "0", "support_material": "0",
    })
    return out


def slic3r_ini(p: Profile, plate_size_mm: tuple[float, float], build_height_mm: float) -> dict[str, str]:
    """Slic3r 1.3 options for ``p``: layer markers by template, move comments for ;TYPE:."""
    out = _common(p, plate_size_mm)
    out.update({
        "top_infill_pattern": "rectilinear", "bottom_infill_pattern": "rectilinear",
        "fill_gaps": "1", "gcode_comments": "1", "support_material": "0", "raft_layers": "0",
        "before_layer_gcode": ";LAYER_CHANGE\\n;Z:[layer_z]\\n",
    })
    return out


def _write_ini(options: dict[str, str], path: Path) -> None:
    path.write_text("".join(f"{k} = {v}\n" for k, v in options.items()), encoding="utf-8")


@functools.cache
def external_version(name: str) -> str | None:
    """Installed version of an external back-end, or None when it is not installed."""
    spec = EXTERNAL.get(name)
    if spec is None or shutil.which(spec["exe"]) is None:
        return None
    try:
        proc = subprocess.run([spec["exe"], *spec["version_args"]], capture_output=True, text=True,
                              timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return None
    match = re.search(spec["version_re"], proc.stdout + proc.stderr)
    return match.group(1) if match else "unknown"


_SLIC3R_KINDS = {"perimeter": "Perimeter", "infill": "Infill", "skirt": "Skirt/Brim", "brim": "Skirt/Brim",
                 "support material": "Support material"}
_SLIC3R_TAG = re.compile(r"^(G1 [^;\n]*E[^;\n]*?)\s*; (perimeter|infill|skirt|brim|support material)\s*$")


def _slic3r_types(gcode: str) -> str:
    """Replace Slic3r's per-move comments by PrusaSlicer-style ;TYPE: markers."""
    out = []
    kind = ""
    for line in gcode.splitlines():
        m = _SLIC3R_TAG.match(line)
        if m:
            k = _SLIC3R_KINDS[m.group(2)]
            if k != kind:
                out.append(f";TYPE:{k}")
                kind = k
            out.append(m.group(1))
        elif line.startswith(";LAYER_CHANGE"):
            kind = ""
            out.append(line)
        else:
            out.append(line)
    return "\n".join(out) + "\n"


EXTERNAL: dict[str, dict] = {
    "prusaslicer": {
        "exe": "prusa-slicer", "version_args": ["--help"], "version_re": r"PrusaSlicer-([0-9][^\s+]*)",
        "ini": prusaslicer_ini,
        "argv": lambda ini, out, model: ["prusa-slicer", "--loglevel=1", "--export-gcode", "--load", ini,
                                         "--dont-arrange", "-o", out, model],
        "post": None,
    },
    "slic3r": {
        "exe": "slic3r", "version_args": ["--version"], "version_re": r"([0-9]+\.[0-9]+\.[0-9]+)",
        "ini": slic3r_ini,
        "argv": lambda ini, out, model: ["slic3r", "--no-gui", "--load", ini, "--dont-arrange",
                                         "-o", out, model],
        "post": _slic3r_types,
    },
}


def run_external(name: str, mesh: trimesh.Trimesh, profile: Profile, plate_size_mm: tuple[float, float],
                 build_height_mm: float, progress: Callable[[float], None] | None = None) -> str:
    """Slice the placed ``mesh`` with an external back-end and return its G-code (conventions applied)."""
    spec = EXTERNAL.get(name)
    if spec is None:
        raise NotFound(f"unknown external slicer {name!r}", backend=name, known=sorted(EXTERNAL))
    if external_version(name) is None:
        raise NotFound(f"slicer back-end {name!r} is not installed ({spec['exe']} not found)",
                       backend=name, executable=spec["exe"])
    report = progress or (lambda _f: None)
    with tempfile.TemporaryDirectory(prefix=f"fabric-{name}-") as tmp:
        work = Path(tmp)
        model = work / "model.stl"
        mesh.export(model, file_type="stl")
        ini = work / "profile.ini"
        _write_ini(spec["ini"](profile, plate_size_mm, build_height_mm), ini)
        out = work / "out.gcode"
        report(0.05)
        argv = spec["argv"](str(ini), str(out), str(model))
        try:
            proc = subprocess.run(argv, capture_output=True, text=True, timeout=TIMEOUT_S, cwd=tmp)
        except subprocess.TimeoutExpired as exc:
            raise SlicerError(f"{name} did not finish within {TIMEOUT_S:.0f} s", backend=name,
                              timeout_s=TIMEOUT_S) from exc
        except OSError as exc:
            raise SlicerError(f"{name} could not be started: {exc}", backend=name) from exc
        if proc.returncode != 0 or not out.is_file():
            tail = [ln for ln in (proc.stderr or proc.stdout or "").splitlines() if ln.strip()][-_STDERR_LINES:]
            raise SlicerError(f"{name} failed with exit code {proc.returncode}: " + (" | ".join(tail[-3:]) or
                              "no output"), backend=name, exit_code=proc.returncode, stderr_tail=tail)
        report(0.9)
        gcode = out.read_text(encoding="utf-8", errors="replace")
    return spec["post"](gcode) if spec["post"] else gcode
