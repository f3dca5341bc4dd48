"""The state banner: one coloured line that says what the station is doing and why, faults first."""
from __future__ import annotations

from typing import Any

from rich.text import Text
from textual.reactive import reactive
from textual.widgets import Static

from fabric.schemas import states
from fabric.tui.format import STATE_STYLE

HEAT_MARGIN_C = 3.0     # below its set point by more than this, a heater counts as still heating


def heating_text(temps: Any) -> str:
    """``nozzle 120/205 C`` for each heater still short of its set point ("" when none is)."""
    if temps is None:
        return ""
    parts = [f"{name} {now:.0f}/{target:.0f} C" for name, now, target in
             (("nozzle", temps.nozzle_c, temps.nozzle_target_c), ("bed", temps.bed_c, temps.bed_target_c))
             if target > 0 and now < target - HEAT_MARGIN_C]
    return ", ".join(parts)


class StateBanner(Static):
    """Attributes: ``state`` (StationState), ``temps``, ``extrusion``, ``alive`` (service -> bool)."""

    state: reactive[Any] = reactive(None, always_update=True)
    temps: reactive[Any] = reactive(None, always_update=True)
    extrusion: reactive[Any] = reactive(None, always_update=True)
    alive: reactive[dict] = reactive(dict, always_update=True)

    def render(self) -> Text:
        st = self.state
        down = [name for name, up in self.alive.items() if not up]
        if st is None:
            word, style, why = "NO STATION", "bold white on red", "no state from the station yet"
        else:
            state = states.Station(st.state)
            word, style, why = state.upper(), STATE_STYLE.get(state, "white"), st.reason
            heating = heating_text(self.temps)
            extruding = self.extrusion is not None and self.extrusion.on
            if state.printing and heating and not extruding:
                word, style, why = "HEATING", "black on yellow", f"waiting for {heating} before printing"
            elif state is states.Station.PAUSED and ("interlock" in why.lower() or "prevented" in why.lower()):
                word, style = "INTERLOCK", "bold white on dark_orange3"
            elif state is states.Station.IDLE and not st.program_id:       # the first thing a new operator reads
                why = (why + ": " if why else "") + "no program; a submits a file (the samples are listed there)"
                if not st.plate_clear:
                    why += f"; the plate holds a part ({st.plate_mm3:.0f} mm3)"
        text = Text(f" {word} ", style=f"{style} bold")
        if why:
            text.append(f" {why}")
        robot = getattr(st, "robot", None)
        if robot is not None:                   # the robot the station drives: how it is, first when it is not
            text.append(f"  {robot.line()}", style="green" if robot.ok else "bold red")
        if down:
            text.append(f"  services down: {', '.join(down)}", style="bold red")
        text.no_wrap, text.overflow = True, "ellipsis"
        return text
