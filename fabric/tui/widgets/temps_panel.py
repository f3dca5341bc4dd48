"""Nozzle and bed temperatures with their set points, and a live graph of the last minutes with its legend and
time axis."""
from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np
from rich.text import Text
from textual.reactive import reactive
from textual.widgets import Static

from fabric.printjobs.history import duration_text
from fabric.tui.braille import BrailleCanvas

HISTORY_S = 300.0            # the graph's span (wall clock)
SAMPLE_PERIOD_S = 0.5        # one sample kept per this much wall time
NOZZLE_STYLE, BED_STYLE = "red1", "dodger_blue1"
LABEL_W = 4                  # the temperature labels left of the graph ("237 ")


class TempsPanel(Static):
    """Attributes: ``temps`` (Temps), ``cell`` (the cell they come from). Each new value is kept (at most every
    SAMPLE_PERIOD_S) for the graph; another cell's temperatures start a new graph (never one curve of two)."""

    temps: reactive[Any] = reactive(None, always_update=True)
    cell: reactive[str] = reactive("")

    def __init__(self, clock: Callable[[], float] = time.monotonic, **kw: Any) -> None:
        super().__init__(**kw)
        self.clock = clock
        self.history: deque[tuple[float, float, float, float, float]] = deque(maxlen=2000)

    def watch_cell(self) -> None:
        self.history.clear()

    def watch_temps(self, t: Any) -> None:
        if t is None:
            return
        now = self.clock()
        if self.history and now - self.history[-1][0] < SAMPLE_PERIOD_S:
            self.history[-1] = (self.history[-1][0], t.nozzle_c, t.nozzle_target_c, t.bed_c, t.bed_target_c)
        else:
            self.history.append((now, t.nozzle_c, t.nozzle_target_c, t.bed_c, t.bed_target_c))
        while self.history and now - self.history[0][0] > HISTORY_S:
            self.history.popleft()

    def render(self) -> Text:
        t = self.temps
        if t is None:
            return Text("waiting for temperatures ...", style="dim")
        text = Text(no_wrap=True, overflow="crop")
        text.append("nozzle ", style=NOZZLE_STYLE).append(f"{t.nozzle_c:5.1f} / {t.nozzle_target_c:5.1f} C")
        text.append("  ━ now", style="grey62").append("\n")
        text.append("bed    ", style=BED_STYLE).append(f"{t.bed_c:5.1f} / {t.bed_target_c:5.1f} C")
        text.append("  ┄ set", style="grey62")
        rows = self.content_size.height - 3          # the two lines above, the time axis below
        if rows >= 2 and len(self.history) >= 2:
            text.append("\n").append(self._graph(self.content_size.width - LABEL_W, rows))
        return text

    def _graph(self, width: int, height: int) -> Text:
        """Temperatures over the last HISTORY_S (or since the console started): dotted set points, solid
        readings; the top value on the left, the time (minutes ago) under it."""
        h = np.array(self.history)
        top_c = max(50.0, float(h[:, 1:].max()) * 1.1)
        canvas = BrailleCanvas(width, height)
        w_px, h_px = canvas.size_px
        span_s = min(HISTORY_S, max(h[-1, 0] - h[0, 0], 10.0))      # fill the width until the history is full
        x = (h[:, 0] - (h[-1, 0] - span_s)) / span_s * (w_px - 1)
        y = lambda c: (h_px - 1) * (1 - c / top_c)  # noqa: E731
        for col, style in ((2, NOZZLE_STYLE), (4, BED_STYLE)):
            xs = np.arange(0, w_px, 4)
            canvas.dots(xs, np.interp(xs, x, y(h[:, col])), f"dim {style}")
        for col, style in ((1, NOZZLE_STYLE), (3, BED_STYLE)):
            yc = y(h[:, col])
            canvas.lines(x[:-1], yc[:-1], x[1:], yc[1:], style, rank=1)
        labels = [f"{top_c:3.0f}"] + ["   "] * (height - 2) + ["  0"]
        out = Text(no_wrap=True, overflow="crop")
        for label, row in zip(labels, canvas.rows(), strict=True):
            out.append(label + " ", style="grey50").append(row).append("\n")
        ago, now = f"-{duration_text(span_s)}", "now"
        out.append(" " * LABEL_W + ago + " " * max(width - len(ago) - len(now), 1) + now, style="grey50")
        return out
