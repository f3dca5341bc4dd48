"""The built-in slicer pipeline: placed mesh + profile -> G-code, with progress.

Stages: layer heights and the section of all layers at once
(:mod:`.layers`); perimeters and infill areas per island (:mod:`.regions`,
memoised on the island's exact geometry and layer height, so a prismatic part
computes each distinct cross-section once), with their gap fill
(:mod:`.gapfill`) and travel regions; the solid / sparse split; bridges
(:mod:`.bridges`); line infill (:mod:`.infill`, memoised on region, angle
and spacing); ordering, seams and travel routes (:mod:`.toolpath`,
:mod:`.travel`) and G-code (:mod:`.writer`). Infill direction alternates by
90 degrees from layer to layer; ``grid`` lays both directions on every layer
at half the density each; bridges take their own direction.
"""
from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import shapely
import trimesh

from fabric.slicing.builtin.bridges import Bridge, find_bridges
from fabric.slicing.builtin.infill import chain_segments, extend_to, scan_segments
from fabric.slicing.builtin.layers import (
    layer_heights,
    rings_to_polygons,
    section_rings,
)
from fabric.slicing.builtin.regions import (
    FillSplit,
    Island,
    classify_fill,
    clean,
    island_perimeters,
    offset,
)
from fabric.slicing.builtin.toolpath import (
    LOOP_CLIP_R,
    loop_path,
    order_gaps,
    order_islands,
    order_loops,
    seam_point,
)
from fabric.slicing.builtin.travel import OUTLINE_MARGIN_MM, TravelPiece, TravelPlanner, travel_pieces
from fabric.slicing.builtin.writer import GcodeWriter
from fabric.slicing.flow import bead_spacing_mm, width_for_spacing_mm
from fabric.slicing.profile import Profile
from fabric.wire.errors import MeshError

__all__ = ["BuiltinOutput", "slice_mesh"]

_SPARSE_INSET_R = 0.05      # sparse lines stop 5 % of a spacing inside the infill area
_SOLID_INSET_R = 0.5        # solid lines stop half a spacing inside it (the links run there)
_LINK_MAX_R = 3.0           # solid links longer than 3 spacings become travels
_RESOLUTION_MM = 0.005      # outline simplification tolerance (PrusaSlicer writes G-code at 0.0125)
_MAX_THREADS = 4            # geometry stages run on threads (GEOS releases the GIL)


@dataclass
class BuiltinOutput:
    """What the built-in slicer produced."""

    gcode: str
    layers: int
    extruded_mm3: float
    filament_mm: float
    volume_by_type_mm3: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    timings_s: dict[str, float] = field(default_factory=dict)
    retractions: int = 0
    travel_mm: float = 0.0
    bridge_area_mm2: float = 0.0          # summed over layers


def slice_mesh(mesh: trimesh.Trimesh, profile: Profile,
               progress: Callable[[float], None] | None = None) -> BuiltinOutput:
    """Slice a mesh already placed in bed coordinates (mm, lowest point at Z = 0) into G-code.

    ``progress`` is called with the fraction done (0..1, increasing). Raises
    MeshError when nothing of the part can be printed with this profile.
    """
    report = progress or (lambda _f: None)
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    warnings: list[str] = []
    p = profile
    top_mm = float(mesh.bounds[1, 2])
    tops, thick = layer_heights(top_mm, p.layer_height_mm, p.first_layer_height_mm)
    planes = tops - thick / 2.0
    xy, ring_start, ring_plane, open_chains = section_rings(mesh, planes)
    if open_chains:
        warnings.append(f"{open_chains} open contours dropped while slicing (mesh not closed there)")
    # Drop collinear points (a prism cut through its slanted side edges gives the same outline
    # with extra points on straight sides) and normalise, so equal outlines have equal bytes.
    raw = np.asarray(rings_to_polygons(xy, ring_start, ring_plane, len(planes)), dtype=object)
    slices = list(shapely.normalize(clean(shapely.simplify(raw, _RESOLUTION_MM))))
    if all(s.is_empty for s in slices):
        raise MeshError("the model has no cross-section to print", reason="empty-slices")
    gaps = [i for i, s in enumerate(slices) if s.is_empty]
    if gaps:
        warnings.append(f"{len(gaps)} layers have nothing to print (first at Z {tops[gaps[0]]:.3f} mm): "
                        "part of the model floats above what is below it")
    keys = [bytes(k) if k is not None else b"" for k in shapely.to_wkb(np.asarray(slices, dtype=object))]
    timings["section"] = time.perf_counter() - t0
    report(0.15)

    # perimeters and infill areas, per distinct island (memoised on geometry + layer height)
    layer_keys: list[list[tuple[bytes, float]]] = []
    todo: dict[tuple[bytes, float], shapely.Geometry] = {}
    for i, sl in enumerate(slices):
        keys_i = []
        for part in shapely.get_parts(sl):
            key = (shapely.to_wkb(part), float(thick[i]))
            todo.setdefault(key, part)
            keys_i.append(key)
        layer_keys.append(keys_i)
    workers = max(1, min(_MAX_THREADS, os.cpu_count() or 1))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        made = pool.map(lambda kv: island_perimeters(kv[1], p.perimeters, p.extrusion_width_mm, kv[0][1],
                                                     p.infill_overlap_r), todo.items())
        cache = dict(zip(todo.keys(), made, strict=True))
        islands = [[cache[k] for k in keys_i] for keys_i in layer_keys]
        timings["perimeters"] = time.perf_counter() - t0 - timings["section"]
        report(0.35)
        fills = [_union([isl.fill for isl in layer]) for layer in islands]
        splits = classify_fill(fills, slices, keys, p.top_solid_layers, p.bottom_solid_layers,
                               p.infill_density_r, bead_mm=p.extrusion_width_mm, pool=pool)

        def bridges_of(i: int) -> list[Bridge]:
            if i == 0 or splits[i].solid.is_empty:
                return []
            return find_bridges(splits[i].solid, slices[i], slices[i - 1], splits[i - 1].sparse,
                                bead_spacing_mm(p.extrusion_width_mm, float(thick[i])))
        bridges = list(pool.map(bridges_of, range(len(slices))))
    timings["classify"] = time.perf_counter() - t0 - sum(timings.values())
    report(0.5)

    writer = GcodeWriter(p)
    writer.start([f"generated by am-fabric built-in slicer, profile {p.name}",
                  f"layer_height = {p.layer_height_mm}", f"first_layer_height = {p.first_layer_height_mm}",
                  f"extrusion_width = {p.extrusion_width_mm}", *p.material_header(),
                  "E is relative (M83), mm of filament"])
    lo, hi = mesh.bounds
    centre_xy = (float(lo[0] + hi[0]) / 2.0, float(lo[1] + hi[1]) / 2.0)
    fill_cache: dict[tuple, list[tuple[np.ndarray, float]]] = {}
    piece_cache: dict[int, tuple[list[TravelPiece], list[TravelPiece]]] = {}
    routes: dict[tuple, np.ndarray | None] = {}
    bridge_area = 0.0
    for i in range(len(slices)):
        h = float(thick[i])
        writer.layer(float(tops[i]), h)
        for isl in islands[i]:
            if id(isl) not in piece_cache:
                piece_cache[id(isl)] = (travel_pieces(isl.travel),
                                        travel_pieces(clean(offset(isl.outline, -OUTLINE_MARGIN_MM))))
        pieces = [pc for isl in islands[i] for pc in piece_cache[id(isl)][0]]
        outline_pieces = [pc for isl in islands[i] for pc in piece_cache[id(isl)][1]]
        writer.router = TravelPlanner(pieces, p.retract_min_travel_mm, p.retract_inside_max_mm, routes,
                                      outline_pieces).plan
        first = i == 0
        speed = {k: (p.first_layer_speed_mm_s if first else v) for k, v in (
            ("peri", p.perimeter_speed_mm_s), ("solid", p.solid_infill_speed_mm_s),
            ("sparse", p.infill_speed_mm_s), ("bridge", p.bridge_speed_mm_s))}
        if first and p.skirt_loops > 0:
            _skirt(writer, slices[0], p, h)
        split = splits[i]
        bridge_area += sum(b.region.area for b in bridges[i])
        here = (writer.x, writer.y) if not math.isnan(writer.x) else centre_xy
        for island in order_islands(islands[i], here, p.seam):
            for loop in order_loops(island, (writer.x, writer.y)):
                seam = seam_point(loop, p.seam, (writer.x, writer.y))
                path = loop_path(loop, seam, LOOP_CLIP_R * p.nozzle_diameter_mm)
                writer.extrude(path, "External perimeter" if loop.depth == 0 else "Perimeter",
                               p.extrusion_width_mm, h, speed["peri"])
            for gap in order_gaps(island.gaps, (writer.x, writer.y)):
                writer.extrude(gap.xy, "Gap fill", float(np.mean(gap.widths_mm)), h, speed["solid"],
                               widths_mm=gap.widths_mm)
            _infill(writer, island, split, bridges[i], i, h, p, speed, fill_cache, len(islands[i]) > 1,
                    centre_xy)
        if i % 8 == 0:
            report(0.5 + 0.5 * i / len(slices))
    writer.end()
    if not set(writer.by_type) - {"Skirt/Brim"}:
        raise MeshError(f"nothing to print: the part is narrower than one {p.extrusion_width_mm} mm bead "
                        "everywhere", reason="too-small", extrusion_width_mm=p.extrusion_width_mm)
    timings["toolpaths"] = time.perf_counter() - t0 - sum(timings.values())
    report(1.0)
    gcode = writer.text()
    return BuiltinOutput(gcode=gcode, layers=len(slices), extruded_mm3=writer.filament_mm * p.filament_area_mm2,
                         filament_mm=writer.filament_mm, volume_by_type_mm3=dict(writer.by_type),
                         warnings=warnings, timings_s=timings, retractions=writer.retractions,
                         travel_mm=writer.travel_mm, bridge_area_mm2=bridge_area)


def _union(parts: list[shapely.Geometry]) -> shapely.Geometry:
    parts = [g for g in parts if not g.is_empty]
    if not parts:
        return shapely.Polygon()
    return parts[0] if len(parts) == 1 else shapely.union_all(parts)


def _infill(writer: GcodeWriter, island: Island, split: FillSplit, bridges: list[Bridge], layer: int, h: float,
            p: Profile, speed: dict[str, float], cache: dict[tuple, list[tuple[np.ndarray, float]]],
            clip_to_island: bool, centre_xy: tuple[float, float]) -> None:
    """Bridges, solid (top-surface part marked) then sparse infill of one island.

    Offsets follow PrusaSlicer's rectilinear fill: solid lines end half a
    spacing inside the infill area, where the links between them run;
    sparse lines end 5 % of a spacing inside it, and a sparse line that does
    not reach half a spacing in (it would only graze the perimeters) is
    dropped. Grid lines are cut half a spacing in, and lines within one
    spacing of the area's extremes are left out.
    """
    if island.fill.is_empty:
        return
    spacing = bead_spacing_mm(p.extrusion_width_mm, h)
    base = math.radians(p.infill_angle_deg) - math.pi / 2.0    # scan lines run at 90 deg to the rotation
    angle = base + (math.pi / 2.0 if layer % 2 else 0.0)
    jobs: list[tuple[str, shapely.Geometry, str, float]] = []
    solid, top, sparse = split.solid, split.top, split.sparse
    if not solid.is_empty:
        if clip_to_island:
            solid = clean(shapely.intersection(solid, island.fill))
        for bridge in bridges:
            if solid.is_empty:
                break
            region = clean(shapely.intersection(bridge.region, solid))
            if region.is_empty or region.area < 1e-4:
                continue
            jobs.append(("Bridge infill", region, "bridge", bridge.angle_rad - math.pi / 2.0))
            solid = clean(shapely.difference(solid, region))
        if solid.is_empty:
            pass
        elif not top.is_empty:
            top = clean(shapely.intersection(top, solid))
            jobs += [("Solid infill", clean(shapely.difference(solid, top)), "solid", angle),
                     ("Top solid infill", top, "solid", angle)]
        else:
            jobs.append(("Solid infill", solid, "solid", angle))
    if not sparse.is_empty and p.infill_density_r > 0:
        if clip_to_island:
            sparse = clean(shapely.intersection(sparse, island.fill))
        jobs.append(("Internal infill", sparse, p.infill_pattern, angle))
    for kind, region, how, ang in jobs:
        if region.is_empty or region.area < 1e-4:
            continue
        start = (round(writer.x, 3), round(writer.y, 3))
        key = (shapely.to_wkb(region), how, ang, h, start)
        if key not in cache:
            cache[key] = _fill_region(region, "solid" if how == "bridge" else how, ang, base, spacing, h, p, start,
                                      centre_xy)
        sp = speed["solid"] if how == "solid" else speed["bridge"] if how == "bridge" else speed["sparse"]
        flow = p.bridge_flow_r if how == "bridge" else 1.0
        for line, width in cache[key]:
            writer.extrude(line, kind, width, h, sp, flow_r=flow)


def _fill_region(region: shapely.Geometry, how: str, angle: float, base: float, spacing: float, h: float,
                 p: Profile, start: tuple[float, float], centre_xy: tuple[float, float]
                 ) -> list[tuple[np.ndarray, float]]:
    """Polylines (with their bead width) filling ``region`` solid, rectilinear or grid."""
    inner = offset(region, -_SOLID_INSET_R * spacing)
    outer = offset(region, -_SPARSE_INSET_R * spacing)
    if how == "solid":
        seg, used = scan_segments(inner, angle, spacing, solid=True, frame=region)
        rim, _ = scan_segments(outer, angle, spacing, solid=True, frame=region)
        seg = extend_to(seg, rim)
        width = width_for_spacing_mm(used, h)
        return [(pl, width) for pl in chain_segments(seg, start, _LINK_MAX_R * used)]
    if how == "grid":
        line_spacing = 2.0 * spacing / p.infill_density_r
        out = []
        for ang in (base, base + math.pi / 2.0):
            seg, _ = scan_segments(inner, ang, line_spacing, solid=False, frame=region,
                                   grid_origin_xy=centre_xy, margin_mm=spacing)
            out += [(pl, p.extrusion_width_mm) for pl in chain_segments(seg, start, 0.0)]
            if out:
                start = (float(out[-1][0][-1, 0]), float(out[-1][0][-1, 1]))
        return out
    line_spacing = spacing / p.infill_density_r
    rim, _ = scan_segments(outer, angle, line_spacing, solid=False, grid_origin_xy=centre_xy)
    seg, _ = scan_segments(inner, angle, line_spacing, solid=False, grid_origin_xy=centre_xy)
    seg = extend_to(seg, rim)
    return [(pl, p.extrusion_width_mm) for pl in chain_segments(seg, start, 0.0)]


def _skirt(writer: GcodeWriter, first: shapely.Geometry, p: Profile, h: float) -> None:
    """Skirt loops around the first layer's convex hull."""
    hull = shapely.convex_hull(first)
    spacing = bead_spacing_mm(p.extrusion_width_mm, h)
    for k in range(p.skirt_loops - 1, -1, -1):
        ring = shapely.buffer(hull, p.skirt_distance_mm + p.extrusion_width_mm / 2 + k * spacing,
                              quad_segs=8)
        xy = np.asarray(ring.exterior.coords)[:, :2]
        writer.extrude(xy, "Skirt/Brim", p.extrusion_width_mm, h, p.first_layer_speed_mm_s)
