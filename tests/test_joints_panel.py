"""The console's joints panel shows any number of joints: one a line while they fit, two a line when not."""
from __future__ import annotations

import asyncio
from types import SimpleNamespace

from textual.app import App, ComposeResult

from fabric.tui.widgets.joints_panel import JointsPanel


class _PanelApp(App):
    CSS = "JointsPanel { height: %d; }"

    def __init__(self, height: int) -> None:
        self.CSS = _PanelApp.CSS % height
        super().__init__()

    def compose(self) -> ComposeResult:
        yield JointsPanel()


def _render(n_joints: int, height: int, width: int = 120, lo_deg: float = -170.0) -> list[str]:
    async def run() -> list[str]:
        app = _PanelApp(height)
        async with app.run_test(size=(width, 20)) as pilot:
            panel = app.query_one(JointsPanel)
            panel.limits = ([lo_deg] * n_joints, [170.0] * n_joints)
            panel.pose = SimpleNamespace(xyz_mm=[1.0, 2.0, 3.0], q_deg=[10.0 * j for j in range(n_joints)])
            await pilot.pause()
            return str(panel.render()).splitlines()
    return asyncio.run(run())


def test_seven_joints_one_a_line_when_they_fit() -> None:
    lines = _render(7, 8)
    assert len(lines) == 8 and lines[0].startswith("TCP") and lines[7].startswith("A7")


def test_seven_joints_two_a_line_in_a_short_panel() -> None:
    lines = _render(7, 7)                  # the wide layout's robot panel: 7 lines inside its border
    assert len(lines) == 5 and lines[1].startswith("A1") and "A2" in lines[1] and lines[4].startswith("A7")
    six = _render(6, 7)                    # six joints in 7 lines: one a line, as before
    assert len(six) == 7 and all("A" + str(j + 1) in six[j + 1] for j in range(6))


def test_two_a_line_fit_a_narrow_panel_instead_of_wrapping() -> None:
    """The wide layout's robot panel is about 68 cells inside: two joints with full bars and three-digit limits
    (-166..166) did not fit, and the second's limits wrapped onto the next line, under the next joint."""
    for width, ranges in ((68, True), (52, False)):
        lines = _render(7, 7, width=width, lo_deg=-166.0)
        assert len(lines) == 5 and all(len(line) <= width for line in lines), lines
        assert ("-166..170" in lines[1].split("A2")[1]) is ranges, lines
        assert lines[4].startswith("A7") and "▏" in lines[4]
