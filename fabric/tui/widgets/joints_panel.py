"""TCP pose and the joints, each against its limits, with a warning when one comes near a limit.

Any number of joints: one line each while they fit under the TCP line; when the
panel is shorter than that (a 7-axis arm in the wide layout's 7-line panel)
the joints go two to a line, in columns, their bars shortened (then their
limits left out) so that two fit the panel's width instead of wrapping a
limit onto the next joint's line.
"""
from __future__ import annotations

from typing import Any

from rich.text import Text
from textual.reactive import reactive
from textual.widgets import Static

NEAR_LIMIT_R = 0.05          # within 5 % of its range of a limit: warn
BAR_CELLS = 10
MIN_BAR_CELLS = 4            # two joints a line: bars no shorter than this, else the limits are left out
COLUMN_GAP = 2


def joint_line(i: int, q_deg: float, lo_deg: float | None, hi_deg: float | None, bar_cells: int = BAR_CELLS,
               show_range: bool = True) -> Text:
    """``A1  -12.3 ▕────●───────▏ -180..180`` (``⚠`` and red when near a limit)."""
    text = Text(f"A{i + 1} {q_deg:7.1f}° ")
    if lo_deg is None or hi_deg is None or hi_deg <= lo_deg:
        return text.append("(limits unknown)", style="dim")
    r = (q_deg - lo_deg) / (hi_deg - lo_deg)
    near = r < NEAR_LIMIT_R or r > 1 - NEAR_LIMIT_R
    style = "bold red" if near else "green"
    pos = min(bar_cells - 1, max(0, int(r * bar_cells)))
    text.append("▕" + "─" * pos, style="grey50").append("●", style=style)
    text.append("─" * (bar_cells - 1 - pos) + "▏", style="grey50")
    if show_range:
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
        n = len(p.q_deg)
        lower, upper = self.limits if self.limits and len(self.limits[0]) == n else ([None] * n, [None] * n)
        rows = self.content_size.height - 1             # under the TCP line (0 before the first layout)
        per_line = 2 if 0 < rows < n else 1
        lines = self._joint_lines(p.q_deg, lower, upper, per_line)
        width = max((t.cell_len for t in lines), default=0) + COLUMN_GAP
        for k in range(0, n, per_line):
            for j, text in enumerate(lines[k:k + per_line]):
                if j:
                    out.append(" " * (width - lines[k].cell_len))
                out.append(text)
            if k + per_line < n:
                out.append("\n")
        return out

    def _joint_lines(self, q_deg: list[float], lower: list, upper: list, per_line: int) -> list[Text]:
        """Each joint's line; two a line, the longest bars (then without limits) with which two fit the width."""
        def make(bar_cells: int, show_range: bool) -> list[Text]:
            return [joint_line(i, q, lower[i], upper[i], bar_cells, show_range) for i, q in enumerate(q_deg)]

        lines = make(BAR_CELLS, True)
        room = self.content_size.width
        if per_line == 1 or room <= 0:
            return lines
        for show_range in (True, False):
            for bar_cells in range(BAR_CELLS, MIN_BAR_CELLS - 1, -1):
                lines = make(bar_cells, show_range)
                if 2 * max(t.cell_len for t in lines) + COLUMN_GAP <= room:
                    return lines
        return lines
