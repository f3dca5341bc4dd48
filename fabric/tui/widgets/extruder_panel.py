"""Extruder on/off and flow, the overrides in force, the deposited volume, the plate and the services'
liveliness."""
from __future__ import annotations

from typing import Any

from rich.text import Text
from textual.reactive import reactive
from textual.widgets import Static

from fabric.tui.format import plate_text
from fabric.wire.keys import SERVICES


class ExtruderPanel(Static):
    """Attributes: ``extrusion`` (Extrusion), ``state`` (StationState), ``alive`` (service -> bool),
    ``degraded`` (service -> the reasons it is degraded; [] or missing = ok)."""

    extrusion: reactive[Any] = reactive(None, always_update=True)
    state: reactive[Any] = reactive(None, always_update=True)
    alive: reactive[dict] = reactive(dict, always_update=True)
    degraded: reactive[dict] = reactive(dict, always_update=True)

    def render(self) -> Text:
        e, st = self.extrusion, self.state
        out = Text(no_wrap=True, overflow="crop")
        if e is None:
            out.append("extruder: no data yet\n", style="dim")
        else:
            out.append(" ON  ", style="bold black on green") if e.on else out.append(" off ", style="grey62 on grey23")
            out.append(f" flow {e.flow_mm3_s:6.2f} mm3/s\n")
        if st is not None:
            rtf = "max" if st.rtf == 0 else f"{st.rtf:g}"
            out.append(f"speed x{st.speed_r:.2f}  flow x{st.flow_r:.2f}  rtf {rtf}\n")
            out.append(f"deposited {st.deposited_mm3:.0f}/{st.planned_mm3:.0f} mm3\n")
            out.append(plate_text(st, whose=False) + "\n", style="" if st.plate_clear else "yellow")
        sick = []
        width, used = max(self.content_size.width, 20), 0
        for name in SERVICES:                    # whole names, on as many lines as the width needs
            up, why = self.alive.get(name), self.degraded.get(name)
            style = "red" if not up else ("yellow" if why else "green")
            if used and used + len(name) + 2 > width:
                out.append("\n")
                used = 0
            out.append("●" if up else "○", style=style).append(f"{name} ")
            used += len(name) + 2
            if up and why:
                sick.append(f"{name}: {why[0]}")
        for line in sick:
            out.append(f"\nDEGRADED {line}", style="yellow")
        return out
