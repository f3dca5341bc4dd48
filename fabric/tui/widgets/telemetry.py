"""Live panels: pose, extrusion, temperatures and the job's state/progress."""
from __future__ import annotations

from typing import Any

from textual.reactive import reactive
from textual.widgets import Static


class PosePanel(Static):
    pose: reactive[Any] = reactive(None, always_update=True)

    def render(self) -> str:
        p = self.pose
        if p is None:
            return "[b]position[/b]\nwaiting for pose ..."
        x, y, z = p.xyz_mm
        q = "  ".join(f"{v:7.2f}" for v in p.q_deg)
        return (f"[b]position[/b]  t_sim {p.t_sim_s:9.2f} s\n"
                f"TCP (plate)  x {x:8.2f}  y {y:8.2f}  z {z:8.2f} mm\n"
                f"joints (deg) {q}")


class ExtrusionPanel(Static):
    extrusion: reactive[Any] = reactive(None, always_update=True)
    temps: reactive[Any] = reactive(None, always_update=True)

    def render(self) -> str:
        e, t = self.extrusion, self.temps
        lines = ["[b]extruder[/b]"]
        if e is not None:
            state = "[green]ON[/green] " if e.on else "off"
            lines.append(f"{state} flow {e.flow_mm3_s:7.2f} mm3/s  x{e.flow_r:.2f}  "
                         f"extruded {e.extruded_mm3:9.1f} mm3  layer {e.layer + 1}")
        if t is not None:
            lines.append(f"nozzle {t.nozzle_c:6.1f} / {t.nozzle_target_c:5.1f} C   "
                         f"bed {t.bed_c:5.1f} / {t.bed_target_c:5.1f} C")
        return "\n".join(lines)


class StatePanel(Static):
    state: reactive[Any] = reactive(None, always_update=True)

    def render(self) -> str:
        st = self.state
        if st is None:
            return "[b]station[/b]\nno state yet"
        colour = {"printing": "green", "paused": "yellow", "fault": "red", "stopped": "red"}.get(st.state, "white")
        remaining = st.remaining_s
        return (f"[b]station[/b]  [{colour}]{st.state.upper()}[/{colour}] {st.reason}\n"
                f"layer {max(st.layer, 0) + (1 if st.layer >= 0 else 0)}/{st.layers_total}   "
                f"{100 * st.progress_r:5.1f} %   elapsed {st.elapsed_s:8.1f} s  remaining {remaining:8.1f} s\n"
                f"speed x{st.speed_r:.2f}  flow x{st.flow_r:.2f}  rtf {'max' if st.rtf == 0 else f'{st.rtf:g}'}")
