"""TCP pose and the joints, each against its limits, with a warning when one comes near a limit."""
from __future__ import annotations

from typing import Any

from rich.text import Text
from textual.reactive import reactive
from textual.widgets import Static

NEAR_LIMIT_R = 0.05          # within 5 % of its range of a limit: warn
BAR_CELLS = 10


def joint_line(i: int, q_deg: float, lo_deg: float | None, hi_deg: float | None) -> Text:
    """``A1  -12.3 ▕────●───────▏ ±180`` (``⚠`` and red when near a limit)."""
    text = Text(f"A{i + 1} {q_deg:7.1f}° ")
    if lo_deg is None or hi_deg is None or hi_deg <= lo_deg:
        return text.append("(limits unknown)", style="dim")
    r = (q_deg - lo_deg) / (hi_deg - lo_deg)
    near = r < NEAR_LIMIT_R or r > 1 - NEAR_LIMIT_R
    style = "bold red" if near else "green"
    pos = min(BAR_CELLS - 1, max(0, int(r * BAR_CELLS)))
    text.append("▕" + "─" * pos, style="grey50").append("●", style=style)
    text.append("─" * (BAR_CELLS - 1 - pos) + "▏", style="grey50")
    text.append(f" {lo_deg:.0f}..{hi_deg:.0f}", style="grey62")
    if near:
        text.append(" ⚠", style="bold red")
    return text


class JointsPanel(Static):
    """Attributes: ``pose`` (Pose) and ``limits`` ((lower_deg, upper_deg) lists, or None while unknown)."""

    pose: reactive[Any] = reactive(None, always_update=True)
    limits: reactive[Any] = reactive(None, always_update=True)

    def render(self) -> Text:
        p = self.pose
        if p is None:
            return Text("waiting for the pose ...", style="dim")
        x, y, z = p.xyz_mm
        out = Text(f"TCP {x:7.1f} {y:7.1f} {z:6.1f} mm\n", no_wrap=True, overflow="crop")
        lower, upper = self.limits if self.limits else ([None] * len(p.q_deg), [None] * len(p.q_deg))
        for i, q in enumerate(p.q_deg):
            out.append(joint_line(i, q, lower[i], upper[i]))
            if i < len(p.q_deg) - 1:
                out.append("\n")
        return out
