"""The Cell screen: state banner, progress and ETA, temperatures, robot, extruder and the live layer view."""
from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from textual.app import ComposeResult
from textual.containers import Container
from textual.events import Resize
from textual.screen import Screen
from textual.widgets import Footer, Header

from fabric.schemas import states
from fabric.tui.widgets.banner import StateBanner
from fabric.tui.widgets.extruder_panel import ExtruderPanel
from fabric.tui.widgets.job_progress import JobProgress
from fabric.tui.widgets.joints_panel import JointsPanel
from fabric.tui.widgets.reply_line import ReplyLine
from fabric.tui.widgets.temps_panel import TempsPanel
from fabric.tui.widgets.toolpath_view import ToolpathView

WIDE_COLS, WIDE_ROWS = 120, 36     # from this size on, the layer view takes a column of its own


class CellScreen(Screen):
    """Watches the console's state (app attributes) and hands it down to its widgets. ``wall_clock`` gives
    the time the ETA is counted from, ``monotonic_clock`` the one the temperature graph is drawn against."""

    def __init__(self, wall_clock: Callable[[], float] = time.time,
                 monotonic_clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self.wall_clock, self.monotonic_clock = wall_clock, monotonic_clock

    def compose(self) -> ComposeResult:
        yield Header()
        yield StateBanner(id="banner")
        yield JobProgress(clock=self.wall_clock, id="progress")
        with Container(id="cell-grid"):
            yield TempsPanel(clock=self.monotonic_clock, id="temps")
            yield ToolpathView(id="toolpath")
            yield JointsPanel(id="joints")
            yield ExtruderPanel(id="extruder")
        yield ReplyLine(id="reply")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        self._pose_shown: tuple | None = None           # what the panels show of the last pose and extrusion
        self._extrusion_shown: tuple | None = None
        for widget_id, title in (("temps", "temperatures"), ("toolpath", "layer"), ("joints", "robot"),
                                 ("extruder", "extruder")):
            self.query_one(f"#{widget_id}").border_title = title
        app = self.app
        self.watch(app, "station_state", self._on_state)
        self.watch(app, "pose", self._on_pose)
        self.watch(app, "extrusion", self._on_extrusion)
        self.watch(app, "temps", self._on_temps)
        self.watch(app, "alive", self._on_alive)
        self.watch(app, "degraded", self._on_degraded)
        self.watch(app, "toolpath", lambda tp: setattr(self.query_one(ToolpathView), "toolpath", tp))
        self.watch(app, "collision_hit", lambda hit: setattr(self.query_one(ToolpathView), "hit", hit))
        self.watch(app, "limits", lambda lim: setattr(self.query_one(JointsPanel), "limits", lim))
        self.watch(app, "reply", self.query_one(ReplyLine).show)
        self.watch(app, "cell", lambda cell: setattr(self.query_one(TempsPanel), "cell", cell))

    def on_resize(self, event: Resize) -> None:
        self.set_class(event.size.width >= WIDE_COLS and event.size.height >= WIDE_ROWS, "wide")

    # --- attributes down -------------------------------------------------------------

    def _on_state(self, st: Any) -> None:
        self.query_one(StateBanner).state = st
        self.query_one(JobProgress).state = st
        self.query_one(ExtruderPanel).state = st
        if st is not None:
            view = self.query_one(ToolpathView)
            view.printing = states.Station(st.state).printing    # a hit's layer is shown unless a print is followed
            view.layer_index = st.layer

    # a sample that shows nothing new (a robot at rest, an extruder off) repaints nothing: the station
    # samples at 50 Hz whatever moves, and each repaint of these panels costs the console a few ms

    def _on_pose(self, pose: Any) -> None:
        shown = None if pose is None else (tuple(pose.q_deg), tuple(pose.xyz_mm))
        if shown is not None and shown == self._pose_shown:
            return
        self._pose_shown = shown
        self.query_one(JointsPanel).pose = pose
        if pose is not None:
            self.query_one(ToolpathView).nozzle_xyz_mm = list(pose.xyz_mm)

    def _on_extrusion(self, e: Any) -> None:
        shown = None if e is None else (e.on, e.flow_mm3_s, e.row)
        if shown is not None and shown == self._extrusion_shown:
            return
        self._extrusion_shown = shown
        self.query_one(StateBanner).extrusion = e
        self.query_one(ExtruderPanel).extrusion = e
        if e is not None:
            self.query_one(ToolpathView).row_index = e.row      # the layer shown is the state's (one count)

    def _on_temps(self, t: Any) -> None:
        self.query_one(StateBanner).temps = t
        self.query_one(TempsPanel).temps = t

    def _on_degraded(self, degraded: dict) -> None:
        self.query_one(ExtruderPanel).degraded = dict(degraded)

    def _on_alive(self, alive: dict) -> None:
        self.query_one(StateBanner).alive = dict(alive)
        self.query_one(ExtruderPanel).alive = dict(alive)
