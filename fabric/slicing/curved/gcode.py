"""The multi-axis G-code dialect: every move carries the nozzle axis as I J K.

``G1 X Y Z I J K E F``: X Y Z is the nozzle tip in the plate frame (mm,
absolute), I J K the unit nozzle axis in the plate frame, pointing from the tip
up the nozzle (``I0 J0 K1`` is a vertical nozzle), E relative filament (mm).
Travels are ``G0 X Y Z I J K F``. The header states the dialect with
``; multiaxis: nozzle axis in I J K``; the rest follows the built-in writer's
conventions (no homing, temperatures, M83, ``;LAYER_CHANGE`` / ``;Z:`` /
``;HEIGHT:`` / ``;TYPE:`` markers), with ``;Z:`` the highest tip of the layer
and ``;HEIGHT:`` its nominal thickness. The axis is modal like X Y Z, but this
writer repeats it on every move so each line stands alone.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fabric.slicing.curved.paths import CurvedPath
from fabric.slicing.curved.travel import HeightMap, crossing
from fabric.slicing.profile import Profile

__all__ = ["MULTIAXIS_HEADER", "GcodeTotals", "write_multiaxis"]

MULTIAXIS_HEADER = "multiaxis: nozzle axis in I J K"
TYPE_NAMES = {"perimeter": "Perimeter", "solid infill": "Solid infill", "infill": "Internal infill"}
TRAVEL_LIFT_MM = 1.0          # travels that retract leave and approach along the nozzle axis by this much
END_CLEARANCE_MM = 2.0        # the print ends with the nozzle upright this far over the part's highest bead
# no move turns the nozzle more than this: the twin (and a controller's joint interpolation) moves the joints
# linearly between two targets, and the tip strays from the straight line the more the nozzle turns (0.05 mm
# for 1 degree, 0.3 mm for 5 on the multi-axis cell): a move that turns more is written in equal pieces
MAX_TURN_DEG = 1.0


@dataclass
class GcodeTotals:
    """What the written program extrudes and how often it stops."""

    gcode: str
    filament_mm: float
    extruded_mm3: float
    retractions: int
    travel_mm: float


def _bead_areas_mm2(width_mm: float, heights_mm: np.ndarray) -> np.ndarray:
    """:func:`fabric.slicing.flow.bead_area_mm2` for many heights at once."""
    return heights_mm * (width_mm - heights_mm * (1.0 - math.pi / 4.0))


_MOVE = "G1 X{:.3f} Y{:.3f} Z{:.3f} I{:.4f} J{:.4f} K{:.4f} E{:.5f}"
_DECIMALS = (3, 3, 3, 4, 4, 4, 5)          # the decimals of _MOVE's fields


def _xyz_ijk(p: np.ndarray, a: np.ndarray) -> str:
    return f"X{p[0]:.3f} Y{p[1]:.3f} Z{p[2]:.3f} I{a[0]:.4f} J{a[1]:.4f} K{a[2]:.4f}"


def write_multiaxis(layers: list[list[CurvedPath]], profile: Profile, header: list[str],
                    nominal_mm: float, tip_radius_mm: float = 0.0) -> GcodeTotals:
    """G-code of the ordered paths of every layer, in the multi-axis dialect. Travels cross over the part as
    printed so far with a nozzle tip of ``tip_radius_mm`` clear of it (:mod:`.travel`)."""
    p = profile
    out: list[str | int] = [f"; {MULTIAXIS_HEADER}"]
    out += [f"; {line}" for line in header + p.material_header()]
    out += [";TYPE:Custom", f"M140 S{p.bed_temp_c:g}", f"M104 S{p.nozzle_temp_c:g}",
            f"M190 S{p.bed_temp_c:g}", f"M109 S{p.nozzle_temp_c:g}",
            "G21 ; millimetres", "G90 ; absolute XYZ", "M83 ; relative E", "G92 E0"]
    travel_f, retract_f = p.travel_speed_mm_s * 60.0, p.retract_speed_mm_s * 60.0
    lift = max(p.retract_lift_mm, TRAVEL_LIFT_MM)
    area_in = p.extrusion_multiplier_r / p.filament_area_mm2
    filament = extruded = travel = 0.0
    retractions = 0
    retracted = False
    here: np.ndarray | None = None
    here_axis = np.array([0.0, 0.0, 1.0])
    blocks: list[np.ndarray] = []          # the extruding moves of each path, (k, 7) X Y Z I J K E
    feeds: list[str] = []
    ends = np.vstack([np.zeros((0, 3))] + [np.vstack([path.points_mm.min(axis=0), path.points_mm.max(axis=0)])
                                           for layer in layers for path in layer])
    heights = HeightMap(ends.min(axis=0), ends.max(axis=0)) if len(ends) else HeightMap(np.zeros(3), np.zeros(3))
    at: np.ndarray | None = None            # where the nozzle tip is, and its axis
    at_axis = np.array([0.0, 0.0, 1.0])

    def go(point: np.ndarray, axis: np.ndarray) -> None:
        """A travel move to ``point`` with the nozzle along ``axis`` (in pieces that turn it little)."""
        nonlocal at, at_axis, travel
        if at is None:
            out.append(f"G0 {_xyz_ijk(point, axis)} F{travel_f:.0f}")
        else:
            pieces, piece_axes, _share = _turn_pieces(np.vstack([at, point]), np.vstack([at_axis, axis]))
            for q, a in zip(pieces, piece_axes, strict=True):
                out.append(f"G0 {_xyz_ijk(q, a)} F{travel_f:.0f}")
            travel += float(np.linalg.norm(point - at))
        at, at_axis = point, axis

    def retract() -> None:
        nonlocal retracted, retractions
        if not retracted and p.retract_length_mm > 0:
            out.append(f"G1 E{-p.retract_length_mm:.5f} F{retract_f:.0f}")
            retractions += 1
            retracted = True

    for index, paths in enumerate(layers):
        if not paths:
            continue
        top = max(float(path.points_mm[:, 2].max()) for path in paths)
        lifted = False
        if here is not None:
            # leave the last layer along the nozzle axis before the next one begins: the tip's edge may reach
            # into the layer under the one it laid, which the next layer's moves may no longer touch
            if float(np.linalg.norm(paths[0].points_mm[0] - here)) > p.retract_min_travel_mm:
                retract()
            go(here + here_axis * lift, here_axis)
            lifted = True
        out += [";LAYER_CHANGE", f";Z:{top:.3f}", f";HEIGHT:{nominal_mm:.3f}"]
        kind = ""
        for path in paths:
            start, axis0 = path.points_mm[0], path.axes[0]
            above = start + axis0 * lift
            if here is None:                    # the first bead: come down onto it along its axis
                go(above, axis0)
                go(start, axis0)
            elif lifted or float(np.linalg.norm(start - here)) > p.retract_min_travel_mm:
                # (retract,) leave along the nozzle axis, cross clear of the part, come down along the next axis
                if not lifted:
                    retract()
                    go(here + here_axis * lift, here_axis)
                assert at is not None
                for point, axis in crossing(at, here_axis, above, axis0, heights, tip_radius_mm):
                    go(point, axis)
                go(above, axis0)
                go(start, axis0)
                lifted = False
            elif float(np.linalg.norm(start - here)) > 0.0:
                go(start, axis0)
            if retracted:
                out.append(f"G1 E{p.retract_length_mm:.5f} F{retract_f:.0f}")
                retracted = False
            if TYPE_NAMES[path.role] != kind:
                kind = TYPE_NAMES[path.role]
                out.append(f";TYPE:{kind}")
                out.append(f";WIDTH:{path.width_mm:.3f}")
            speed = p.first_layer_speed_mm_s if index == 0 else (
                p.perimeter_speed_mm_s if path.role == "perimeter" else
                p.solid_infill_speed_mm_s if path.role == "solid infill" else p.infill_speed_mm_s)
            feed = f" F{speed * 60.0:.0f}"
            seg = np.linalg.norm(np.diff(path.points_mm, axis=0), axis=1)
            volumes = seg * _bead_areas_mm2(path.width_mm, 0.5 * (path.heights_mm[1:] + path.heights_mm[:-1]))
            es = volumes * area_in
            pts, axes, share = _turn_pieces(path.points_mm, path.axes)
            blocks.append(np.column_stack([pts, axes, es[share[0]] * share[1]]))
            feeds.append(feed)
            out.append(len(blocks) - 1)          # the block's moves are formatted all at once below
            filament += float(es.sum())
            extruded += float(volumes.sum()) * p.extrusion_multiplier_r
            here, here_axis = path.points_mm[-1], path.axes[-1]
            at, at_axis = here, here_axis
            heights.add(path.points_mm)
    if not retracted and p.retract_length_mm > 0 and here is not None:
        out.append(f"G1 E{-p.retract_length_mm:.5f} F{retract_f:.0f}")
        retractions += 1
    if here is not None:
        # end over the part with the nozzle upright: off the last bead along its axis, then straight up clear of
        # the part, turning upright on the way (the planner's return home rises from there along the axis: 50 mm
        # along a tilted last axis took the hook's wrist past its limit)
        go(here + here_axis * lift, here_axis)
        assert at is not None
        clear = max(float(np.max(heights.z)), float(at[2])) + END_CLEARANCE_MM
        go(np.array([at[0], at[1], clear]), np.array([0.0, 0.0, 1.0]))
    out += [";TYPE:Custom", "M104 S0", "M140 S0", ""]
    moves = _format_moves(np.vstack(blocks)) if blocks else []
    first = np.r_[0, np.cumsum([len(b) for b in blocks])].tolist()
    text: list[str] = []
    for line in out:
        if isinstance(line, str):
            text.append(line)
        else:                                   # a path's moves, the first with the path's feed rate
            text.append(moves[first[line]] + feeds[line])
            text += moves[first[line] + 1:first[line + 1]]
    return GcodeTotals("\n".join(text), filament, extruded, retractions, travel)


def _turn_pieces(points_mm: np.ndarray, axes: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray,
                                                                                                np.ndarray]]:
    """The moves through ``points_mm`` (n, 3) with ``axes`` (n, 3), each of the n - 1 cut into equal pieces that
    turn the axis at most :data:`MAX_TURN_DEG`: their end points (m, 3), axes (m, 3), and for each piece the
    move it is part of and the share of it (to split the move's extrusion)."""
    cos = np.clip(np.einsum("ij,ij->i", axes[1:], axes[:-1]), -1.0, 1.0)
    count = np.maximum(np.ceil(np.degrees(np.arccos(cos)) / MAX_TURN_DEG - 1e-9), 1).astype(np.int64)
    move = np.repeat(np.arange(len(count)), count)
    frac = (np.arange(len(move)) - np.repeat(np.cumsum(count) - count, count) + 1) / count[move]
    pts = points_mm[move] + frac[:, None] * (points_mm[move + 1] - points_mm[move])
    ax = axes[move] + frac[:, None] * (axes[move + 1] - axes[move])
    ax /= np.maximum(np.linalg.norm(ax, axis=1, keepdims=True), 1e-12)
    return pts, ax, (move, 1.0 / count[move])


def _digit_table(digits: int) -> np.ndarray:
    """ASCII codes (10^digits, digits) of every number below 10^digits, zero-padded."""
    values = np.arange(10 ** digits)
    return np.stack([(values // 10 ** (digits - 1 - k)) % 10 for k in range(digits)], axis=1).astype(np.uint8) \
        + np.uint8(ord("0"))


def _fixed_column(values: np.ndarray, decimals: int, codes: np.ndarray, used: np.ndarray) -> None:
    """Write ``values`` with ``decimals`` decimals, as ``f"{v:.{decimals}f}"`` writes them (a minus sign on
    negative values and negative zero), into the ASCII ``codes`` (n, w) and mark which of them ``used`` (the
    integer part is right-aligned after the sign slot, in the width of the largest)."""
    raw = np.abs(values) * 10.0 ** decimals
    scaled = np.rint(raw).astype(np.int64)
    for i in np.flatnonzero(np.abs(raw - np.floor(raw) - 0.5) < 1e-6).tolist():
        # within rounding of a tie: the product's rounding may differ from the exact decimal value's
        scaled[i] = int(f"{abs(float(values[i])):.{decimals}f}".replace(".", ""))
    whole, frac = np.divmod(scaled, 10 ** decimals)
    width = codes.shape[1] - 2 - decimals
    codes[:, 0] = ord("-")
    used[:, 0] = np.signbit(values)
    codes[:, 1:1 + width] = _digit_table(width)[whole]
    powers = 10 ** np.arange(width - 1, -1, -1)
    used[:, 1:1 + width] = (whole[:, None] >= powers) | (powers == 1)
    codes[:, 1 + width] = ord(".")
    used[:, 1 + width:] = True
    codes[:, 2 + width:] = _digit_table(decimals)[frac]


def _format_moves(rows: np.ndarray) -> list[str]:
    """``_MOVE.format(*row)`` for every row of (n, 7) ``X Y Z I J K E``, built as one byte array (formatting
    millions of floats one by one took a tenth of a large part's slicing time)."""
    n = len(rows)
    names = ("G1 X", " Y", " Z", " I", " J", " K", " E")
    widths = [len(str(int(np.rint(np.abs(rows[:, c]).max())))) if n else 1 for c in range(7)]
    total = sum(len(name) + 2 + w + d for name, w, d in zip(names, widths, _DECIMALS, strict=True)) + 1
    codes = np.empty((n, total), dtype=np.uint8)
    used = np.empty((n, total), dtype=bool)
    at = 0
    for column, (name, width, decimals) in enumerate(zip(names, widths, _DECIMALS, strict=True)):
        codes[:, at:at + len(name)] = np.frombuffer(name.encode(), dtype=np.uint8)
        used[:, at:at + len(name)] = True
        at += len(name)
        span = 2 + width + decimals
        _fixed_column(rows[:, column], decimals, codes[:, at:at + span], used[:, at:at + span])
        at += span
    codes[:, at] = ord("\n")
    used[:, at] = True
    return codes[used].tobytes().decode("ascii").split("\n")[:-1]
