"""The layer view marks a collision check's first hit (issue 18): the widget drawn alone, then the console with a
stand-in client (the hit's layer shown, the mark cleared by a clean check, another program or another cell)."""
from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest
from test_tui_snapshots import square_layers
from textual.app import App, ComposeResult

from fabric import schemas as s
from fabric.motion.program import MOVEL, PRINT, Program
from fabric.programs import program_artifact
from fabric.tui.app import FabricConsole
from fabric.tui.messages import ProgramReady
from fabric.tui.screens.confirm import ConfirmDialog
from fabric.tui.screens.report import ReportDialog
from fabric.tui.widgets.toolpath_view import HIT_GLYPH, NOZZLE_GLYPH, ToolpathView
from fabric.wire.errors import CollisionError

from support.tui_stub import StubClient

pytestmark = pytest.mark.timeout(60)

HIT = s.CollisionHit(body_a="tool_nozzle", body_b="part", row=20, gcode_line=345, layer=1, kind="travel",
                     xyz_mm=[100.0, 110.0, 0.9], bead=7, bead_layer=1)


class ViewApp(App):
    """The layer view alone, 40 x 12 cells of content."""

    CSS = "ToolpathView { width: 40; height: 12; padding: 0; border: none; }"

    def compose(self) -> ComposeResult:
        yield ToolpathView()


def cell_of(view: ToolpathView, xy_mm: list[float]) -> tuple[int, int]:
    """The (row, column) of the character cell that holds plate point ``xy_mm`` in ``view``."""
    w, h = view.content_size.width, view.content_size.height
    to_px = view._scale(view.toolpath.bounds_mm, (2 * w, 4 * h))
    (x,), (y,) = to_px(np.asarray([xy_mm], dtype=float))
    return int(y) // 4, int(x) // 2


def glyphs(view: ToolpathView) -> dict[str, list[tuple[int, int]]]:
    """Where each non-braille character is drawn: glyph -> [(row, column)]."""
    out: dict[str, list[tuple[int, int]]] = {}
    for r, line in enumerate(view.render().plain.split("\n")):
        for c, ch in enumerate(line):
            if not 0x2800 <= ord(ch) <= 0x28FF:
                out.setdefault(ch, []).append((r, c))
    return out


def test_the_view_draws_the_hit_where_it_is_and_says_so_in_its_title():
    async def scenario() -> None:
        app = ViewApp()
        async with app.run_test(size=(60, 20)) as pilot:
            view = app.query_one(ToolpathView)
            view.toolpath = square_layers()
            view.layer_index = 2
            view.nozzle_xyz_mm = [120.0, 130.0, 0.9]
            await pilot.pause()
            assert HIT_GLYPH not in glyphs(view) and view.border_title == "layer 3/4"
            # a hit on layer 2 while nothing prints: that layer is shown, the hit marked, the title says where
            view.hit = HIT
            await pilot.pause()
            drawn = glyphs(view)
            assert drawn[HIT_GLYPH] == [cell_of(view, HIT.xyz_mm[:2])]
            assert drawn[NOZZLE_GLYPH] == [cell_of(view, [120.0, 130.0])] and HIT_GLYPH != NOZZLE_GLYPH
            assert view.border_title == "layer 2/4 · hit line 345"
            (row, col), = drawn[HIT_GLYPH]
            assert view.render().split("\n")[row][col:col + 1].spans[0].style == "bold yellow1 on red3"
            # printing layer 3: the view follows the print; the hit is on another layer, named, not marked
            view.printing = True
            await pilot.pause()
            assert HIT_GLYPH not in glyphs(view) and view.border_title == "layer 3/4 · hit on layer 2"
            view.layer_index = 1                                     # the print reaches the hit's layer
            await pilot.pause()
            assert glyphs(view)[HIT_GLYPH] == [cell_of(view, HIT.xyz_mm[:2])]
            assert view.border_title == "layer 2/4 · hit line 345"
            # a station move's hit (no layer): marked on the layer shown, the title names the move
            view.hit = s.CollisionHit(body_a="link_5", body_b="part", kind="home", xyz_mm=[90.0, 95.0, 30.0])
            await pilot.pause()
            assert glyphs(view)[HIT_GLYPH] == [cell_of(view, [90.0, 95.0])]
            assert view.border_title == "layer 2/4 · hit: home move"
            view.hit = None
            await pilot.pause()
            assert HIT_GLYPH not in glyphs(view) and view.border_title == "layer 2/4"
    asyncio.run(scenario())


# --- the console ---------------------------------------------------------------------------------------------

def program(layers: int = 4, side_mm: float = 40.0) -> Program:
    """Square perimeters, one per layer (the program the stand-in station has loaded)."""
    pts = []
    for k in range(layers):
        z = 0.3 * (k + 1)
        pts += [(x + 80, y + 90, z, flow, k) for x, y, flow in
                ((0, 0, 0.0), (side_mm, 0, 1.0), (side_mm, side_mm, 1.0), (0, side_mm, 1.0), (0, 0, 1.0))]
    prog = Program.empty(len(pts) + 1)
    prog.op[:] = MOVEL
    prog.section[1:] = PRINT
    prog.xyz_mm[1:] = [p[:3] for p in pts]
    prog.xyz_mm[0] = prog.xyz_mm[1]
    prog.flow_mm3_mm[1:] = [p[3] for p in pts]
    prog.layer[1:] = [p[4] for p in pts]
    return prog


class CheckingClient(StubClient):
    """A stand-in whose station answers ``collisions`` with ``self.report``."""

    def __init__(self, cell: str = "cell1", state: s.StationState | None = None) -> None:
        super().__init__(cell, state=state)
        self.report = s.CollisionReport(collision_free=True, checked_configs=10, min_distance_mm=2.0)
        self.programs: dict[str, s.Artifact] = {}

    def artifact(self, service: str, artifact_id: str, timeout: float = 60.0) -> s.Artifact:
        if artifact_id in self.programs:
            return self.programs[artifact_id]
        return super().artifact(service, artifact_id, timeout)

    def collisions(self) -> s.CollisionReport:
        self._called("collisions")
        return self.report

    def home(self) -> s.Ack:
        """Refused as the station refuses a move its check hits: the hit in the error's details."""
        self._called("home")
        hit = s.CollisionHit(body_a="link_5", body_b="part", kind="home", move_r=0.3, xyz_mm=[110.0, 100.0, 30.0],
                             bead=3, bead_layer=0)
        raise CollisionError("the move home would collide: the home move: link_5 hits the part",
                             **{k: v for k, v in s.to_plain(hit).items() if k != "message"})


def hit_report(hit: s.CollisionHit = HIT) -> s.CollisionReport:
    return s.CollisionReport(collision_free=False, checked_configs=10, min_distance_mm=0.0, first_hit=hit)


async def until(pilot, predicate, timeout_s: float = 10.0, what: str = "condition") -> None:
    end = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < end, f"{what} not reached in {timeout_s:g} s"
        await pilot.pause(0.02)


async def check(pilot, app: FabricConsole) -> None:
    """Press c; wait for the reply and close its report."""
    before = app.reply
    await pilot.press("c")
    await until(pilot, lambda: app.reply is not before and app.reply[0] == "collisions", what="collisions reply")
    await until(pilot, lambda: isinstance(app.screen, ReportDialog), what="the report")
    await pilot.press("escape")
    await until(pilot, lambda: not app.screen.is_modal, what="the report closed")


@pytest.mark.slow                         # 3 s (not the fast tier)
def test_the_console_marks_the_hit_until_a_clean_check_another_program_or_another_cell():
    art = program_artifact(program())
    client = CheckingClient(state=s.StationState(state="ready", program_id=art.artifact_id, layers_total=4))
    client.programs[art.artifact_id] = art

    async def scenario() -> None:
        app = FabricConsole(client)
        async with app.run_test(size=(160, 48), notifications=False) as pilot:
            view = app.screen.query_one(ToolpathView)
            await until(pilot, lambda: view.toolpath is not None, what="the toolpath")
            assert view.border_title == "layer 1/4"
            client.report = hit_report()
            await check(pilot, app)
            assert app.reply[2].startswith("COLLISION") and view.hit == HIT
            await until(pilot, lambda: view.border_title == "layer 2/4 · hit line 345", what="the hit's layer")
            assert glyphs(view)[HIT_GLYPH] == [cell_of(view, HIT.xyz_mm[:2])]
            # a clean check clears it
            client.report = s.CollisionReport(collision_free=True, checked_configs=10, min_distance_mm=2.0)
            await check(pilot, app)
            await until(pilot, lambda: view.hit is None and view.border_title == "layer 1/4", what="cleared")
            assert HIT_GLYPH not in glyphs(view)
            # the same program read again keeps the hit; another program clears it
            client.report = hit_report()
            await check(pilot, app)
            await until(pilot, lambda: view.hit == HIT, what="marked again")
            app.post_message(ProgramReady("cell1", art.artifact_id, view.toolpath))
            await pilot.pause(0.1)
            assert view.hit == HIT
            app.post_message(ProgramReady("cell1", "another", view.toolpath))
            await until(pilot, lambda: view.hit is None, what="cleared by another program")
            assert HIT_GLYPH not in glyphs(view)
            # a report on a program the console does not show (it changed meanwhile) marks nothing
            await check(pilot, app)
            await pilot.pause(0.1)
            assert view.hit is None
            app.post_message(ProgramReady("cell1", art.artifact_id, view.toolpath))      # the loaded one again
            # a live move refused by its check: its hit (no layer) is marked on the layer shown, named by its move
            before = app.reply
            await pilot.press("h")
            await until(pilot, lambda: isinstance(app.screen, ConfirmDialog), what="home confirmation")
            await pilot.press("y")
            await until(pilot, lambda: app.reply is not before and app.reply[0] == "home", what="home reply")
            assert not app.reply[1] and "[collision] the move home would collide" in app.reply[2]
            await until(pilot, lambda: view.hit is not None and view.hit.kind == "home", what="the home hit")
            assert view.border_title == "layer 1/4 · hit: home move" and view.hit.layer == -1
            assert glyphs(view)[HIT_GLYPH] == [cell_of(view, [110.0, 100.0])]
            # another cell: nothing of this one's is kept
            await check(pilot, app)
            await until(pilot, lambda: view.hit == HIT, what="marked on the program shown")
            app._follow(CheckingClient("cell2"))
            await until(pilot, lambda: app.cell == "cell2" and view.hit is None, what="cleared by another cell")
    asyncio.run(scenario())
