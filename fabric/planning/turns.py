"""Multi-axis toolpaths: moves that turn the nozzle a lot, split into pieces that each turn it a little.

A row of the multi-axis dialect goes from the previous point and nozzle axis
to its own. The robot's joints are solved at the row's ends and interpolated
between them, so a row that turns the nozzle by tens of degrees (a travel
from one side of a curved part to the other) leaves the path between its ends
to the joint interpolation, and the planner's joint-jump test cannot tell it
from a change of configuration. Such a row is cut into ``k = ceil(turn /
max_turn_deg)`` equal pieces: the point moves along the straight segment, the
axis turns along the great circle (slerp) by equal angles, and an extruding
row's filament is shared equally. Each piece keeps the row's G-code line,
layer, feature and feed; events that preceded the row precede its first piece.
"""
from __future__ import annotations

import math

import numpy as np

from fabric.gcode.toolpath import Toolpath

__all__ = ["split_turns", "turn_angles_rad"]


def turn_angles_rad(axis: np.ndarray, prev_axis: np.ndarray) -> np.ndarray:
    """The angle (N,) each row turns the nozzle: from the row before it (``prev_axis`` before row 0)."""
    before = np.concatenate([np.asarray(prev_axis, dtype=float).reshape(1, 3), axis[:-1]])
    c = np.einsum("ij,ij->i", before, axis)
    return np.arccos(np.clip(c, -1.0, 1.0))


def _slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Unit vectors between unit vectors ``a`` and ``b`` (M, 3) at fractions ``t`` (M,) along the great circle."""
    c = np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)
    ang = np.arccos(c)
    s = np.sin(ang)
    small = s < 1e-9
    wa = np.where(small, 1.0 - t, np.sin((1.0 - t) * ang) / np.where(small, 1.0, s))
    wb = np.where(small, t, np.sin(t * ang) / np.where(small, 1.0, s))
    out = wa[:, None] * a + wb[:, None] * b
    return out / np.linalg.norm(out, axis=1)[:, None]


def split_turns(tp: Toolpath, max_turn_deg: float, prev_axis: np.ndarray | None = None) -> Toolpath:
    """``tp`` with every row that turns the nozzle more than ``max_turn_deg`` cut into pieces (module docstring).

    ``prev_axis`` is the nozzle axis before row 0 (the last row of the chunk before); None: row 0's own (its turn
    is not known). A planar toolpath, or one with no such row, is returned as it is.
    """
    if tp.axis is None or len(tp) == 0:
        return tp
    axis = tp.axis
    turn = turn_angles_rad(axis, axis[0] if prev_axis is None else prev_axis)
    limit = math.radians(max_turn_deg)
    pieces = np.maximum(np.ceil(turn / limit - 1e-9), 1).astype(np.int64)
    if not (pieces > 1).any():
        return tp
    n = len(tp)
    total = int(pieces.sum())
    row = np.repeat(np.arange(n), pieces)
    first = np.cumsum(pieces) - pieces                    # the first piece of each row
    k = np.arange(total) - first[row]                     # 0 .. pieces - 1 within the row
    t = (k + 1) / pieces[row]
    starts = tp.starts_mm()
    xyz = starts[row] + t[:, None] * (tp.xyz_mm[row] - starts[row])
    before = np.concatenate([(axis[0] if prev_axis is None else np.asarray(prev_axis, float)).reshape(1, 3),
                             axis[:-1]])
    new_axis = _slerp(before[row], axis[row], t)
    last = k == pieces[row] - 1                           # the last piece ends exactly on the row's end
    xyz[last] = tp.xyz_mm[row[last]]
    new_axis[last] = axis[row[last]]
    ev_row = np.where(tp.event_row < n, first[np.minimum(tp.event_row, n - 1)], total)
    return Toolpath(
        start_xyz_mm=tp.start_xyz_mm, xyz_mm=xyz, e_mm=tp.e_mm[row] / pieces[row], feed_mm_s=tp.feed_mm_s[row],
        line=tp.line[row], layer=tp.layer[row], feature=tp.feature[row], feature_names=tp.feature_names,
        event_row=ev_row.astype(tp.event_row.dtype, copy=False), event_kind=tp.event_kind,
        event_value=tp.event_value, event_aux=tp.event_aux, event_line=tp.event_line, layer_z_mm=tp.layer_z_mm,
        unknown_commands=tp.unknown_commands, n_lines=tp.n_lines, slicer=tp.slicer, material=tp.material,
        axis=new_axis)
