"""The current layer's toolpath drawn with braille dots, the nozzle's position on it, live; and where a collision
check found its first hit. Curved layers (a multi-axis program) get a side view under the top view."""
from __future__ import annotations

from typing import Any

import numpy as np
from rich.text import Text
from textual.reactive import reactive
from textual.widgets import Static

from fabric.tui.braille import BrailleCanvas

DONE_STYLE, TODO_STYLE, TRAVEL_STYLE, NOZZLE_STYLE = "green1", "grey50", "grey30", "bold red1"
NOZZLE_GLYPH = "◉"
HIT_GLYPH, HIT_STYLE = "✖", "bold yellow1 on red3"     # a collision check's first hit: not the nozzle's mark


class ToolpathView(Static):
    """Attributes: ``toolpath`` (Toolpath or None), ``layer_index`` (0-based), ``row_index`` (the program row the
    station is at: segments ending before it are printed), ``nozzle_xyz_mm`` (plate frame), ``printing`` (the
    station is printing: the view follows ``layer_index``) and ``hit`` (a collision check's first hit on the
    loaded program, an ``s.CollisionHit``, or None).

    With a hit and no print running, the view shows the hit's layer; while printing it keeps following the
    print and marks the hit only when it is on the layer shown. A hit of no layer (-1: a station's own move,
    home or recover) is marked on the layer shown. The border title says where the hit is."""

    toolpath: reactive[Any] = reactive(None, always_update=True)
    layer_index: reactive[int] = reactive(-1)
    row_index: reactive[int] = reactive(-1)
    nozzle_xyz_mm: reactive[Any] = reactive(None, always_update=True)
    printing: reactive[bool] = reactive(False)
    hit: reactive[Any] = reactive(None, always_update=True)

    def render(self) -> Text:
        tp = self.toolpath
        w, h = self.content_size.width, self.content_size.height
        if tp is None:
            return Text("no program loaded", style="dim")
        if w < 4 or h < 2:
            return Text("")
        if tp.curved and h >= 8:                     # curved layers: the top view over a side view
            side_h = max(3, h // 3)
            top = self._top_view(tp, w, h - side_h)
            return Text("\n").join([top, self._side_view(tp, w, side_h)])
        return self._top_view(tp, w, h)

    def _side_view(self, tp: Any, w: int, h: int) -> Text:
        """The part seen from the front (x across, z up): the layers printed so far dim, the layer shown
        bright (green where printed), and the nozzle; a curved layer shows as the curve it is."""
        layer = self._shown_layer()
        canvas = BrailleCanvas(w, h)
        x_lo, _, x_hi, _ = tp.bounds_mm
        z_lo, z_hi = tp.z_bounds_mm
        to_px = self._scale((x_lo, z_lo, x_hi, z_hi), canvas.size_px)
        below = np.flatnonzero(tp.extruding & (tp.layer < layer))
        if len(below) > 20_000:                      # enough to show the part's shape
            below = below[np.linspace(0, len(below) - 1, 20_000).astype(np.int64)]
        idx = tp.of_layer(layer)
        idx = idx[tp.extruding[idx]]
        done = tp.row[idx] <= self.row_index
        for sel, style, rank in ((below, TRAVEL_STYLE, 0), (idx[~done], TODO_STYLE, 1), (idx[done], DONE_STYLE, 2)):
            (x0, y0) = to_px(np.column_stack([tp.start_xy_mm[sel, 0], tp.start_z_mm[sel]]))
            (x1, y1) = to_px(np.column_stack([tp.end_xy_mm[sel, 0], tp.end_z_mm[sel]]))
            canvas.lines(x0, y0, x1, y1, style, rank)
        if self.nozzle_xyz_mm is not None:
            (nx,), (ny,) = to_px(np.asarray([[self.nozzle_xyz_mm[0], self.nozzle_xyz_mm[2]]], dtype=float))
            canvas.mark(nx, ny, NOZZLE_GLYPH, NOZZLE_STYLE)
        return canvas.render()

    def _top_view(self, tp: Any, w: int, h: int) -> Text:
        layer = self._shown_layer()
        canvas = BrailleCanvas(w, h)
        to_px = self._scale(tp.bounds_mm, canvas.size_px)
        idx = tp.of_layer(layer)
        (x0, y0), (x1, y1) = to_px(tp.start_xy_mm[idx]), to_px(tp.end_xy_mm[idx])
        ext, done = tp.extruding[idx], tp.row[idx] <= self.row_index
        travel = ~ext
        canvas.lines(x0[travel], y0[travel], x1[travel], y1[travel], TRAVEL_STYLE, rank=0)
        for mask, style, rank in ((ext & ~done, TODO_STYLE, 1), (ext & done, DONE_STYLE, 2)):
            canvas.lines(x0[mask], y0[mask], x1[mask], y1[mask], style, rank)
        if self.nozzle_xyz_mm is not None:
            (nx,), (ny,) = to_px(np.asarray([self.nozzle_xyz_mm[:2]], dtype=float))
            canvas.mark(nx, ny, NOZZLE_GLYPH, NOZZLE_STYLE)
        xy = self._hit_xy_mm(layer)
        if xy is not None:                           # drawn last: over the nozzle when they share a cell
            (hx,), (hy,) = to_px(np.asarray([xy], dtype=float))
            canvas.mark(hx, hy, HIT_GLYPH, HIT_STYLE)
        return canvas.render()

    def _shown_layer(self) -> int:
        tp = self.toolpath
        if tp is None:
            return -1
        hit = self.hit
        layer = hit.layer if hit is not None and hit.layer >= 0 and not self.printing else self.layer_index
        return min(max(layer, 0), max(tp.layers_total - 1, 0))

    def _hit_xy_mm(self, layer: int) -> list[float] | None:
        """Where to mark the hit on ``layer`` (plate frame), or None: no hit, no position, another layer."""
        hit = self.hit
        if hit is None or hit.xyz_mm is None or hit.layer not in (-1, layer):
            return None
        return [float(hit.xyz_mm[0]), float(hit.xyz_mm[1])]

    def watch_layer_index(self) -> None:
        self._title()

    def watch_toolpath(self) -> None:
        self._title()

    def watch_printing(self) -> None:
        self._title()

    def watch_hit(self) -> None:
        self._title()

    def _title(self) -> None:
        tp = self.toolpath
        if tp is None:
            self.border_title = "layer"
            return
        shown = self._shown_layer()
        title = f"{'curved ' if tp.curved else ''}layer {shown + 1}/{tp.layers_total}"
        hit = self.hit
        if hit is not None:
            if hit.layer == -1:
                title += f" · hit: {hit.kind or 'station'} move"
            elif hit.layer != shown:
                title += f" · hit on layer {hit.layer + 1}"
            elif hit.gcode_line >= 0:
                title += f" · hit line {hit.gcode_line}"
            else:
                title += " · hit here"
        self.border_title = title

    @staticmethod
    def _scale(bounds_mm: tuple[float, float, float, float], size_px: tuple[int, int]):
        """Plate mm -> dot coordinates: the part's extent fits the canvas, square dots, y up."""
        bx0, by0, bx1, by1 = bounds_mm
        w_px, h_px = size_px
        span_x, span_y = max(bx1 - bx0, 1.0), max(by1 - by0, 1.0)
        k = min((w_px - 3) / span_x, (h_px - 3) / span_y)
        ox = (w_px - span_x * k) / 2 - bx0 * k
        oy = (h_px - span_y * k) / 2 + by1 * k

        def to_px(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return ox + xy[:, 0] * k, oy - xy[:, 1] * k
        return to_px
