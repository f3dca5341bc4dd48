"""Layers and features of the toolpath rows: from the slicer's comment markers, or inferred from Z.

Layer markers (``;LAYER_CHANGE``, ``;LAYER:n`` ...) start a new layer at the
row after them (several markers before the same row count once); a ``;Z:``
marker or a marker's own height gives the layer's Z. Feature markers
(``;TYPE:...``) name what the following rows print. Both are carried from one
block to the next. A file without layer markers gets its layers from Z
(:func:`infer_layers`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from fabric.gcode.dialects import MK_FEATURE, MK_LAYER, MK_Z, find_markers
from fabric.gcode.lexer import Lexed

__all__ = ["LayerTracker", "RowLayers", "Layers", "infer_layers"]


@dataclass
class RowLayers:
    """Layer index (-1 before the first) and feature code of each row of a block."""

    layer: np.ndarray          # (n,) int32
    feature: np.ndarray        # (n,) int16


class Layers(NamedTuple):
    """The layers of a whole toolpath."""

    layer: np.ndarray          # (n,) int32 layer of each row, -1 before the first
    layer_z_mm: np.ndarray     # (layers,) Z of each layer


class LayerTracker:
    """Layer and feature markers of the blocks in order; the layers' Z and the feature names."""

    def __init__(self) -> None:
        self.layer_count = 0
        self.last_marker_row = -1
        self.feature = 0
        self.layer_z: dict[int, float] = {}
        self.features: dict[str, int] = {"none": 0}

    def mark(self, block: bytes | memoryview, lx: Lexed, row_line: np.ndarray, first_row: int) -> RowLayers:
        """Layers and features of a block's rows (``row_line``: their 0-based lines; ``first_row``: the
        index of the block's first row in the whole toolpath)."""
        mk = find_markers(block, lx.line_start, lx.code_end)
        # layer markers: a new layer at the row after each, counted once per row
        lay = np.flatnonzero(mk.kind == MK_LAYER)
        ml = mk.line[lay]
        mrow = first_row + np.searchsorted(row_line, ml, side="left")
        new = mrow != np.concatenate([[self.last_marker_row], mrow[:-1]])
        new_lines = ml[new]
        layer_at = self.layer_count + np.cumsum(new) - 1
        for i in np.flatnonzero(np.isfinite(mk.z_mm[lay])):
            self.layer_z[int(layer_at[i])] = float(mk.z_mm[lay][i])
        # ;Z: markers give the height of the layer they are in
        zi = np.flatnonzero(mk.kind == MK_Z)
        z_layer = self.layer_count - 1 + np.searchsorted(new_lines, mk.line[zi], side="right")
        for layer, z in zip(z_layer, mk.z_mm[zi], strict=True):
            if layer >= 0:
                self.layer_z[int(layer)] = float(z)
        layer = (self.layer_count - 1 + np.searchsorted(new_lines, row_line, side="left")).astype(np.int32)
        self.layer_count += int(new.sum())
        if len(mrow):
            self.last_marker_row = int(mrow[-1])
        # feature markers: the last one before each row (or the one carried from the blocks before)
        fi = np.flatnonzero(mk.kind == MK_FEATURE)
        fcode = np.array([self.features.setdefault(mk.names[i], len(self.features)) for i in fi], np.int16)
        j = np.searchsorted(mk.line[fi], row_line, side="left") - 1
        feature = np.where(j >= 0, fcode[np.maximum(j, 0)] if len(fcode) else 0, self.feature).astype(np.int16)
        if len(fcode):
            self.feature = int(fcode[-1])
        return RowLayers(layer, feature)

    def layers(self, xyz: np.ndarray, e: np.ndarray, marked: np.ndarray) -> Layers:
        """The layers of the whole toolpath: from the markers (a layer's Z defaults to its first
        extruding row's), or inferred from Z when the file had none."""
        if self.layer_count == 0:
            return infer_layers(xyz, e)
        layer_z = np.full(self.layer_count, np.nan)
        ext = np.flatnonzero((e > 0) & (marked >= 0))
        u, first = np.unique(marked[ext], return_index=True)
        layer_z[u] = xyz[ext[first], 2]
        for li, z in self.layer_z.items():
            layer_z[li] = z
        return Layers(marked, layer_z)


def infer_layers(xyz: np.ndarray, e: np.ndarray) -> Layers:
    """Layers from Z: a new layer starts when an extruding move is higher than all before it.

    The layer begins right after the previous layer's last extruding move, so
    the travel (and lift) to the new layer belongs to it; rows before the first
    extrusion are layer -1.
    """
    n = len(e)
    ext = np.flatnonzero(e > 0)
    if len(ext) == 0:
        return Layers(np.full(n, -1, np.int32), np.zeros(0))
    z = xyz[ext, 2]
    new = np.concatenate([[True], z[1:] > np.maximum.accumulate(z)[:-1] + 1e-6])
    ni = np.flatnonzero(new)
    starts = np.where(ni == 0, ext[0], ext[np.maximum(ni - 1, 0)] + 1)
    layer = np.searchsorted(starts, np.arange(n), side="right") - 1
    return Layers(layer.astype(np.int32), z[ni])
