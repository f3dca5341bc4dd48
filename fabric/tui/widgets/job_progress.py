"""The print's progress: a bar, layer n/N, percent, and the wall-clock ETA at the current real-time factor."""
from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from rich.text import Text
from textual.reactive import reactive
from textual.widgets import Static

from fabric.schemas import states
from fabric.tui.format import eta_text, layer_text

# the bar's colour in these station states (green in the others)
PROGRESS_COLOUR = {states.Station.PAUSED: "yellow", states.Station.STOPPED: "dark_orange3",
                   states.Station.FAULT: "red", states.Station.INTERRUPTED: "red"}


class JobProgress(Static):
    """Attribute: ``state`` (StationState). ``clock`` gives the wall time the ETA is counted from."""

    state: reactive[Any] = reactive(None, always_update=True)

    def __init__(self, clock: Callable[[], float] = time.time, **kw: Any) -> None:
        super().__init__(**kw)
        self.clock = clock

    def render(self) -> Text:
        st = self.state
        if st is None or (st.layers_total == 0 and st.total_s == 0):
            return Text(" no program loaded · a submit a file · e preheat · 2 jobs · ? every key", style="dim")
        tail = f" {layer_text(st)}  {100 * st.progress_r:5.1f} %  {eta_text(st, self.clock())}".rstrip()
        bar_w = max(10, self.size.width - len(tail) - 1)
        done = int(round(bar_w * st.progress_r))
        colour = PROGRESS_COLOUR.get(states.Station(st.state), "green")
        text = Text("█" * done, style=colour)
        text.append("░" * (bar_w - done), style="grey42")
        text.append(tail)
        text.no_wrap, text.overflow = True, "crop"
        return text
