"""Toolpath -> the Print section's rows in the plate frame (no kinematics yet), vectorised.

Each toolpath row becomes one linear move at ``feed * speed_r`` (capped), with
the extruder's flow per mm of path ``e * (pi d^2 / 4) / length`` on extruding
rows and 0 elsewhere. Events become non-motion rows placed before the move
they precede: temperatures (SET_TEMP; M109/M190 a WAIT_TEMP, after a SET_TEMP of
its value unless that is the set point already), dwells
(WAIT), extruder-only moves and firmware retractions (RETRACT, signed filament
mm); a retraction *during* a move (negative E while moving) becomes a RETRACT
just before that move. Fan events have no robot instruction and are counted.

Travel lifts: a run of consecutive non-extruding rows whose XY length is at
least ``lift_min_travel_mm`` is lifted by ``travel_lift_mm`` along the plate z:
a move straight up from the last point, the run's points raised, and a move
straight down onto the run's last point. A multi-axis toolpath (rows with
their own nozzle axes, ``Toolpath.axis``) carries each row's axis into the
``axis`` column, and its lifts go along the nozzle axis of each point instead
of the plate z (the same thing for a vertical nozzle).

The whole mapping is array arithmetic: each toolpath row owns a block of output
rows ``[events..., up?, move, down?]`` whose offsets are a cumulative sum.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabric.gcode.toolpath import (
    EV_BED_TEMP,
    EV_DWELL,
    EV_EXTRUDE,
    EV_FAN,
    EV_FW_RETRACT,
    EV_FW_UNRETRACT,
    EV_NOZZLE_TEMP,
    WAIT_NONE,
    Toolpath,
)
from fabric.motion.program import BED, MOVEL, NOZZLE, RETRACT, SET_TEMP, WAIT, WAIT_TEMP
from fabric.motion.thermal import Thermal
from fabric.planning.options import PlanOptions
from fabric.wire.errors import GcodeError, ValidationError

__all__ = ["PrintRows", "map_toolpath"]


@dataclass
class PrintRows:
    """Program columns holding the Print section at rows ``[start, stop)`` (plate frame).

    The arrays are allocated with ``head`` rows before and ``tail`` rows after
    the print rows, so the caller fills in the approach and return rows and
    builds the :class:`~fabric.motion.program.Program` on them without a copy.
    ``first_xyz_mm`` is where the approach lands.
    """

    start: int
    stop: int
    op: np.ndarray
    xyz_mm: np.ndarray
    speed_mm_s: np.ndarray
    zone_mm: np.ndarray
    flow_mm3_mm: np.ndarray
    value: np.ndarray
    aux: np.ndarray
    gcode_line: np.ndarray
    layer: np.ndarray
    first_xyz_mm: np.ndarray
    first_line: int
    axis: np.ndarray | None       # (rows, 3) nozzle axis per row (multi-axis toolpaths); None: vertical
    first_axis: np.ndarray        # (3,) the nozzle axis where the approach lands
    n_lifts: int
    n_fan_events: int

    def __len__(self) -> int:
        return self.stop - self.start


def _events(tp: Toolpath, e: np.ndarray, moving_retract: np.ndarray, opt: PlanOptions
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """Toolpath events (plus retractions while moving) as program ops: (row, op, value, aux, line).

    M109/M190 set the heater's set point and wait for it (as firmware does); a WAIT_TEMP row only waits
    for the set point in force, so a wait whose value is not already set is preceded by a SET_TEMP row
    of its own line (``M109 S200`` alone heats to 200 C; after ``M104 S200`` it adds nothing)."""
    kind, aux, val = tp.event_kind, tp.event_aux, tp.event_value
    ev_row, ev_line = tp.event_row, tp.event_line
    _check_set_points(kind, aux, val, ev_line)
    unset = _unset_waits(kind, aux, val)
    if len(unset):                                # each such wait twice: its SET_TEMP copy first
        copies = np.ones(len(kind), np.intp)
        copies[unset] = 2
        idx = np.repeat(np.arange(len(kind)), copies)
        kind, aux, val, ev_row, ev_line = kind[idx], aux[idx].copy(), val[idx], ev_row[idx], ev_line[idx]
        aux[np.flatnonzero(np.diff(idx) == 0)] = WAIT_NONE
    op = np.full(len(kind), 255, np.uint8)
    heater = np.where(kind == EV_BED_TEMP, BED, NOZZLE)
    temp = (kind == EV_NOZZLE_TEMP) | (kind == EV_BED_TEMP)
    op[temp] = np.where(aux[temp] == WAIT_NONE, SET_TEMP, WAIT_TEMP)
    op[kind == EV_DWELL] = WAIT
    op[kind == EV_EXTRUDE] = RETRACT
    value = val.astype(np.float64).copy()
    if opt.fw_retract_mm > 0:
        op[(kind == EV_FW_RETRACT) | (kind == EV_FW_UNRETRACT)] = RETRACT
        value[kind == EV_FW_RETRACT] = -opt.fw_retract_mm
        value[kind == EV_FW_UNRETRACT] = opt.fw_retract_mm
    keep = op != 255
    mr = np.flatnonzero(moving_retract)
    rows = np.concatenate([ev_row[keep], mr])
    order = np.argsort(rows, kind="stable")
    cat = lambda a, b: np.concatenate([a, b])[order]          # noqa: E731
    return (rows[order], cat(op[keep], np.full(len(mr), RETRACT, np.uint8)), cat(value[keep], e[mr]),
            cat(np.where(temp, heater, 0)[keep].astype(np.int16), np.zeros(len(mr), np.int16)),
            cat(ev_line[keep], tp.line[mr]), int((kind == EV_FAN).sum()))


def _check_set_points(kind: np.ndarray, aux: np.ndarray, val: np.ndarray, line: np.ndarray) -> None:
    """A set point above its heater's maximum is a GcodeError naming the line (negative ones the reader
    refuses already)."""
    params = Thermal().params
    limit = np.where(kind == EV_BED_TEMP, params[BED].max_c, params[NOZZLE].max_c)
    bad = np.flatnonzero(((kind == EV_NOZZLE_TEMP) | (kind == EV_BED_TEMP)) & (val > limit))
    if not len(bad):
        return
    i = int(bad[0])
    bed = int(kind[i]) == EV_BED_TEMP
    code = ("M190" if bed else "M109") if aux[i] != WAIT_NONE else ("M140" if bed else "M104")
    heater = "bed" if bed else "nozzle"
    raise GcodeError(f"{heater} set point {val[i]:g} C is above the {heater} heater's maximum {limit[i]:g} C",
                     line=int(line[i]), text=f"{code} S{val[i]:g}", heater=heater, value=float(val[i]),
                     limit=float(limit[i]))


def _unset_waits(kind: np.ndarray, aux: np.ndarray, val: np.ndarray) -> np.ndarray:
    """Indices of the temperature waits (M109/M190) whose value differs from the set point the heater's
    previous temperature event left (or that have none before them)."""
    out = []
    for ev in (EV_NOZZLE_TEMP, EV_BED_TEMP):
        sel = np.flatnonzero(kind == ev)
        if not len(sel):
            continue
        v = val[sel]
        changed = np.ones(len(sel), bool)
        changed[1:] = v[1:] != v[:-1]
        out.append(sel[(aux[sel] != WAIT_NONE) & changed])
    return np.sort(np.concatenate(out)) if out else np.zeros(0, np.intp)


def map_toolpath(tp: Toolpath, opt: PlanOptions, head: int = 0, tail: int = 0, *, first: bool = True,
                 last: bool = True) -> PrintRows:
    """Map a toolpath (G-code frame) to Print-section rows (plate frame); see the module docstring.

    A toolpath planned in chunks (:class:`~fabric.gcode.ToolpathChunks`: each cut between two extruding
    rows with no event between them, so no travel run or stop straddles a cut) maps chunk by chunk:
    ``first`` says whether this is the first (where the approach may land on row 0's start), ``last``
    whether it is the last (whose last row is a stop).
    """
    n = len(tp)
    if n == 0:
        raise ValidationError("the G-code has no moves", field="gcode", n_lines=tp.n_lines)
    off = np.asarray(opt.offset_mm)
    pts = tp.xyz_mm + off if off.any() else tp.xyz_mm        # read only
    d = np.empty_like(tp.xyz_mm)                  # segment vectors, without a prepended copy
    d[0] = tp.xyz_mm[0] - tp.start_xyz_mm
    np.subtract(tp.xyz_mm[1:], tp.xyz_mm[:-1], out=d[1:])
    seg = np.sqrt(np.einsum("ij,ij->i", d, d))
    e = tp.e_mm
    ext = (e > 0) & (seg > 1e-9)
    # the approach lands on row 0's end unless it extrudes (a later chunk starts with an extruding row)
    k0 = 0 if ext[0] or not first else 1
    start = (tp.start_xyz_mm + off) if k0 == 0 else pts[0]
    ev_row, ev_op, ev_val, ev_aux, ev_line, n_fan = _events(tp, e, (e < 0) & (seg > 1e-9), opt)
    sl = slice(k0, n)
    m = n - k0
    speed = np.minimum(tp.feed_mm_s[sl] * opt.speed_r, opt.max_tcp_speed_mm_s)
    flow = np.where(ext[sl], e[sl] * (opt.filament_area_mm2 / np.maximum(seg[sl], 1e-300)), 0.0)
    # travel runs and their lifts
    travel = ~ext[sl]
    prev_t = np.concatenate([[False], travel[:-1]])
    next_t = np.concatenate([travel[1:], [False]])
    run_start = travel & ~prev_t
    run_end = travel & ~next_t
    lifted = np.zeros(m, bool)
    if opt.travel_lift_mm > 0 and run_start.any():
        run_id = np.cumsum(run_start) - 1
        tr = np.flatnonzero(travel) + k0
        run_xy = np.bincount(run_id[tr - k0], weights=np.hypot(d[tr, 0], d[tr, 1]), minlength=int(run_start.sum()))
        lifted = travel & (run_xy[np.maximum(run_id, 0)] >= opt.lift_min_travel_mm)
        del run_id
    del d, seg, travel, prev_t, next_t                # temporaries go before the columns are allocated
    ui = np.flatnonzero(run_start & lifted)
    di = np.flatnonzero(run_end & lifted)
    # block layout: [events, up, move, down] per toolpath row, trailing events at the end
    slot = np.clip(ev_row, k0, n) - k0
    nev = np.bincount(slot, minlength=m + 1)
    block = nev[:m] + 1
    block[ui] += 1
    block[di] += 1
    offs = np.cumsum(block)
    offs -= block
    total = int(block.sum() + nev[m])
    del block
    main = offs + nev[:m]
    main[ui] += 1
    ev_first = np.cumsum(nev) - nev
    ev_pos = np.full(len(slot), total - nev[m])          # events after the last move go at the end
    inner = slot < m
    ev_pos[inner] = offs[slot[inner]]
    ev_pos += np.arange(len(slot)) - ev_first[slot]
    del offs
    # columns (views into arrays with room for the approach and return rows)
    size = head + total + tail
    axes = tp.axis
    first_axis = np.array([0.0, 0.0, 1.0]) if axes is None else np.array(axes[0], dtype=float)
    full_axis = None if axes is None else np.zeros((size, 3))
    full: dict[str, np.ndarray] = {
        "op": np.full(size, MOVEL, np.uint8), "xyz_mm": np.zeros((size, 3)), "speed_mm_s": np.zeros(size),
        "zone_mm": np.zeros(size), "flow_mm3_mm": np.zeros(size), "value": np.zeros(size),
        "aux": np.zeros(size, np.int16), "gcode_line": np.full(size, -1, np.int64),
        "layer": np.full(size, -1, np.int32)}
    view = {k: v[head:head + total] for k, v in full.items()}
    op, xyz = view["op"], view["xyz_mm"]
    op[ev_pos] = ev_op
    xyz[main] = pts[sl]
    ax = None if full_axis is None or axes is None else full_axis[head:head + total]
    if ax is not None and axes is not None:
        ax[main] = axes[sl]
    if len(ui):
        li = np.flatnonzero(lifted)
        pi = k0 + ui - 1                          # the point the lift starts from
        xyz[main[ui] - 1] = np.where((pi >= 0)[:, None], pts[np.maximum(pi, 0)], start[None])
        xyz[main[di] + 1] = pts[k0 + di]
        if ax is None or axes is None:
            xyz[main[li], 2] += opt.travel_lift_mm
            xyz[main[ui] - 1, 2] += opt.travel_lift_mm
        else:                                     # along each point's nozzle axis
            up_axis = np.where((pi >= 0)[:, None], axes[np.maximum(pi, 0)], first_axis[None])
            xyz[main[li]] += opt.travel_lift_mm * axes[k0 + li]
            xyz[main[ui] - 1] += opt.travel_lift_mm * up_axis
            ax[main[ui] - 1] = up_axis
            ax[main[di] + 1] = axes[k0 + di]
    # an event row repeats the pose of the motion row before it (the first point if none)
    prev_pos = np.full(len(slot), -1)
    after = np.flatnonzero(slot > 0)              # events after some toolpath row: that row's move (or down)
    prev_pos[after] = main[slot[after] - 1] + np.isin(slot[after] - 1, di)
    xyz[ev_pos] = np.where((prev_pos >= 0)[:, None], xyz[np.maximum(prev_pos, 0)], start[None])
    if ax is not None:
        ax[ev_pos] = np.where((prev_pos >= 0)[:, None], ax[np.maximum(prev_pos, 0)], first_axis[None])
    motion = op == MOVEL
    speed_col, line, layer = view["speed_mm_s"], view["gcode_line"], view["layer"]
    t_line, t_layer = tp.line[sl], tp.layer[sl]
    for shift, rows in ((0, slice(None)), (-1, ui), (1, di)):
        at = main if shift == 0 else main[rows] + shift
        speed_col[at] = speed[rows]
        line[at] = t_line[rows]
        layer[at] = t_layer[rows]
    view["flow_mm3_mm"][main] = flow
    line[ev_pos] = ev_line
    layer[ev_pos] = tp.layer[np.minimum(np.clip(ev_row, k0, n), n - 1)]
    view["value"][ev_pos] = ev_val
    view["aux"][ev_pos] = ev_aux
    # blend zones, except into a stop (a non-motion row next) and at the end
    zone = view["zone_mm"]
    zone[motion] = opt.zone_mm
    zone[ev_pos[ev_pos > 0] - 1] = 0.0
    if last:
        zone[-1] = 0.0
    if full_axis is not None and axes is not None:    # the approach and return rows: the end points' axes
        full_axis[:head] = first_axis
        full_axis[head + total:] = full_axis[head + total - 1] if total else first_axis
    return PrintRows(start=head, stop=head + total, **full,
                     first_xyz_mm=np.asarray(start, dtype=float).copy(),
                     first_line=int(tp.line[0]), n_lifts=int(ui.size), n_fan_events=n_fan,
                     axis=full_axis, first_axis=first_axis)
