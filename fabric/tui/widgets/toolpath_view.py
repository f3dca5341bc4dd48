"""The current layer's toolpath drawn with braille dots, the nozzle's position on it, live."""
from __future__ import annotations

from typing import Any

import numpy as np
from rich.text import Text
from textual.reactive import reactive
from textual.widgets import Static

from fabric.tui.braille import BrailleCanvas

DONE_STYLE, TODO_STYLE, TRAVEL_STYLE, NOZZLE_STYLE = "green1", "grey50", "grey30", "bold red1"


class ToolpathView(Static):
    """Attributes: ``toolpath`` (Toolpath or None), ``layer_index`` (0-based), ``row_index`` (the program row the
    station is at: segments ending before it are printed), ``nozzle_xyz_mm`` (plate frame)."""

    toolpath: reactive[Any] = reactive(None, always_update=True)
    layer_index: reactive[int] = reactive(-1)
    row_index: reactive[int] = reactive(-1)
    nozzle_xyz_mm: reactive[Any] = reactive(None, always_update=True)

    def render(self) -> Text:
        tp = self.toolpath
        w, h = self.content_size.width, self.content_size.height
        if tp is None:
            return Text("no program loaded", style="dim")
        if w < 4 or h < 2:
            return Text("")
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
            canvas.mark(nx, ny, "◉", NOZZLE_STYLE)
        return canvas.render()

    def _shown_layer(self) -> int:
        tp = self.toolpath
        return min(max(self.layer_index, 0), max(tp.layers_total - 1, 0)) if tp is not None else -1

    def watch_layer_index(self) -> None:
        self._title()

    def watch_toolpath(self) -> None:
        self._title()

    def _title(self) -> None:
        tp = self.toolpath
        self.border_title = f"layer {self._shown_layer() + 1}/{tp.layers_total}" if tp is not None else "layer"

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
