"""The slicing entry point: model bytes + profile + back-end -> G-code and its figures.

``slice_model`` is what the slicer service calls. It loads and repairs the
model (:mod:`.mesh`), places it on the plate and checks it fits
(:mod:`.placement`), then runs the chosen back-end: ``builtin`` (always
there), ``prusaslicer`` or ``slic3r`` (when installed). Every back-end writes
the same conventions (absolute XYZ in bed coordinates, relative E in mm of
filament, ``;LAYER_CHANGE`` / ``;Z:`` / ``;TYPE:`` markers, no homing), and
the figures in :class:`SliceResult` are measured the same way for all.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any

from fabric.slicing.builtin.slicer import slice_mesh
from fabric.slicing.external import EXTERNAL, external_version, run_external
from fabric.slicing.gcode_stats import gcode_stats
from fabric.slicing.mesh import load_mesh
from fabric.slicing.placement import Placement, place_mesh
from fabric.slicing.profile import Profile
from fabric.wire.errors import BadRequest, NotFound

__all__ = ["SliceResult", "slice_model", "available_backends", "BACKENDS"]

BACKENDS = ("builtin", *EXTERNAL)
LAYER_MODES = ("planar", "curved")


@dataclass
class SliceResult:
    """G-code and what it holds.

    ``extruded_mm3`` is the volume of the beads (E on extruding moves times
    the filament's cross-section); ``filament_mm`` the filament those beads
    use. ``bbox_mm`` is the placed part's bounding box ``[[xmin, ymin, zmin],
    [xmax, ymax, zmax]]`` in bed coordinates. ``elapsed_s`` is the whole call:
    loading, repair, placement and slicing (for external back-ends, their
    process start included). ``retractions`` counts the retractions (each a
    stop of the nozzle), ``travel_mm`` the XY length of the non-extruding
    moves, both read from the G-code for every back-end; ``bridge_area_mm2``
    is the area printed as bridges, summed over layers (for an external
    back-end estimated as its bridge volume over the layer height). ``curved``
    holds a curved-layer slice's measured figures (overhang against planar,
    thickness, tilt, neighbour angles, cusp; empty for planar layers).
    """

    gcode: str
    backend: str
    layers: int
    extruded_mm3: float
    filament_mm: float
    model_volume_mm3: float
    faces: int
    bbox_mm: list[list[float]]
    warnings: list[str] = field(default_factory=list)
    elapsed_s: float = 0.0
    retractions: int = 0
    travel_mm: float = 0.0
    bridge_area_mm2: float = 0.0
    curved: dict[str, float] = field(default_factory=dict)


def _builtin_version() -> str:
    try:
        return metadata.version("am-fabric")
    except metadata.PackageNotFoundError:
        return "dev"


def available_backends() -> dict[str, str | None]:
    """Back-end name -> version, or None when it is not installed."""
    out: dict[str, str | None] = {"builtin": _builtin_version()}
    for name in EXTERNAL:
        out[name] = external_version(name)
    return out


def slice_model(data: bytes, filename: str, profile: Profile, backend: str = "builtin",
                placement: Placement | None = None, plate_size_mm: tuple[float, float] = (250.0, 250.0),
                build_height_mm: float = 250.0,
                progress: Callable[[float], None] | None = None, layers: str = "planar",
                cell: Any = None) -> SliceResult:
    """Slice a model given as bytes (format from ``filename``'s suffix) with ``profile`` on ``backend``.

    ``layers`` "curved" runs the built-in curved-layer slicer (:mod:`.curved`), which writes the
    multi-axis dialect, with nozzle axes the arm of ``cell`` (a :class:`fabric.robot.cell.Cell`, when given)
    holds where the part stands on its plate. Raises NotFound (unknown or missing back-end), BadRequest
    (curved layers on an external back-end), MeshError, PlacementError, SlicerError (an external slicer
    failed).
    """
    t0 = time.perf_counter()
    if backend not in BACKENDS:
        raise NotFound(f"unknown slicer back-end {backend!r} (known: {', '.join(BACKENDS)})",
                       backend=backend, known=list(BACKENDS))
    if layers not in LAYER_MODES:
        raise BadRequest(f"unknown layer mode {layers!r} (known: {', '.join(LAYER_MODES)})", layers=layers)
    if layers == "curved" and backend != "builtin":
        raise BadRequest(f"curved layers need the builtin back-end, not {backend!r}", backend=backend)
    if backend != "builtin" and external_version(backend) is None:
        raise NotFound(f"slicer back-end {backend!r} is not installed", backend=backend)
    report = progress or (lambda _f: None)
    report(0.0)
    mesh = load_mesh(data, filename)
    warnings = [f"repair: {note}" for note in mesh.metadata.get("repairs", [])]
    placed = place_mesh(mesh, placement, plate_size_mm, build_height_mm, notes=warnings)
    report(0.05)

    def sub(lo: float, hi: float) -> Callable[[float], None]:
        return lambda f: report(lo + (hi - lo) * min(max(f, 0.0), 1.0))

    curved: dict[str, float] = {}           # a curved slice's measured figures (curved/metrics.py)
    if layers == "curved":
        from fabric.slicing.curved import slice_curved  # TetGen and the field solvers: only when asked
        cs = slice_curved(placed, profile, progress=sub(0.05, 0.98), cell=cell)
        gcode, layers_n, extruded, filament = cs.gcode, cs.layers, cs.extruded_mm3, cs.filament_mm
        retractions, travel_mm, bridge_mm2 = cs.retractions, cs.travel_mm, 0.0
        warnings += cs.warnings
        curved = {k: float(v) for k, v in cs.report.as_dict().items() if k != "elapsed_s"}
    elif backend == "builtin":
        out = slice_mesh(placed, profile, sub(0.05, 0.98))
        gcode, layers_n, extruded, filament = out.gcode, out.layers, out.extruded_mm3, out.filament_mm
        retractions, travel_mm, bridge_mm2 = out.retractions, out.travel_mm, out.bridge_area_mm2
        warnings += out.warnings
    else:
        gcode = run_external(backend, placed, profile, plate_size_mm, build_height_mm, sub(0.05, 0.95))
        stats = gcode_stats(gcode, profile.filament_diameter_mm)
        layers_n, extruded, filament = stats.layers, stats.extruded_mm3, stats.extruded_filament_mm
        retractions, travel_mm = stats.retractions, stats.travel_mm
        bridge_mm2 = stats.volume_by_type_mm3.get("Bridge infill", 0.0) / profile.layer_height_mm
    report(1.0)
    lo, hi = placed.bounds
    return SliceResult(gcode=gcode, backend=backend, layers=layers_n, extruded_mm3=float(extruded),
                       filament_mm=float(filament), model_volume_mm3=float(placed.volume),
                       faces=int(len(placed.faces)), bbox_mm=[lo.tolist(), hi.tolist()],
                       warnings=warnings, elapsed_s=time.perf_counter() - t0, retractions=int(retractions),
                       travel_mm=float(travel_mm), bridge_area_mm2=float(bridge_mm2), curved=curved)
