"""The operator console: live state of the cell and the paper's commands, over the same client as the CLI."""
from __future__ import annotations

import queue
import time
from typing import Any, Callable

from rich.markup import escape
from textual import work
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.widgets import Button, Footer, Header, RichLog

from fabric.client import AliveSubscription, Client
from fabric.errors import FabricError
from fabric.tui.messages import Liveliness, Telemetry
from fabric.tui.widgets.services import ServicesPanel
from fabric.tui.widgets.telemetry import ExtrusionPanel, PosePanel, StatePanel

TOPICS = ("pose", "extrusion", "temps", "state", "events")
UI_PERIOD_S = 0.1       # pose/extrusion/temps redraw at most this often

COMMANDS: dict[str, tuple[str, Callable[[Client], Any]]] = {
    "start": ("Start", lambda c: c.start()),
    "pause": ("Pause", lambda c: c.pause()),
    "resume": ("Resume", lambda c: c.resume()),
    "stop": ("Stop", lambda c: c.stop()),
    "home": ("Home", lambda c: c.home()),
    "ready": ("Ready?", lambda c: c.ready()),
    "collisions": ("Collisions", lambda c: c.collisions()),
    "calibrate": ("Calibrate", lambda c: c.calibrate()),
}


def describe(command: str, result: Any) -> str:
    """One or a few lines for the log: what the command answered."""
    if command == "ready":
        marks = "  ".join(f"{'✔' if ch.ok else '✘'} {ch.name}" for ch in result.checks)
        return f"{'READY' if result.ready else 'NOT READY'}: {marks}"
    if command == "collisions":
        if result.collision_free:
            return f"collision-free ({result.checked_configs} configs, clearance {result.min_distance_mm:.1f} mm)"
        h = result.first_hit
        return f"COLLISION line {h.gcode_line}: {h.body_a} <-> {h.body_b}"
    if command == "calibrate":
        return (f"plate corrected by {[round(v, 3) for v in result.correction_xyz_mm]} mm, "
                f"residual {result.residual_rms_mm:.4f} mm")
    return getattr(result, "message", "") or "ok"


class FabricConsole(App):
    """``fabric-tui``: services, pose, extruder, state and events; keys or buttons for the commands."""

    CSS_PATH = "console.tcss"
    TITLE = "am-fabric"
    BINDINGS = [Binding("s", "command('start')", "start"), Binding("p", "command('pause')", "pause"),
                Binding("r", "command('resume')", "resume"), Binding("x", "command('stop')", "stop"),
                Binding("h", "command('home')", "home"), Binding("y", "command('ready')", "ready?"),
                Binding("c", "command('collisions')", "collisions"), Binding("k", "command('calibrate')", "calibrate"),
                Binding("q", "quit", "quit")]

    def __init__(self, client: Client) -> None:
        super().__init__()
        self.client = client
        self.sub_title = f"cell {client.keys.cell}"
        self.alive: dict[str, bool] = {}
        self._last_ui: dict[str, float] = {}
        self._subs: list[Any] = []
        self._alive_sub: AliveSubscription | None = None

    def compose(self) -> ComposeResult:
        yield Header()
        with Horizontal(id="top"):
            yield ServicesPanel(id="services")
            with Vertical(id="live"):
                yield StatePanel(id="state")
                yield PosePanel(id="pose")
                yield ExtrusionPanel(id="extrusion")
        with Horizontal(id="buttons"):
            for name, (label, _) in COMMANDS.items():
                yield Button(label, id=f"cmd-{name}", variant="error" if name == "stop" else "default")
        yield RichLog(id="log", markup=True, wrap=True, max_lines=2000)
        yield Footer()

    def on_mount(self) -> None:
        for topic in TOPICS:
            self._subs.append(self.client.subscribe("station", topic))
            self.feed(topic, self._subs[-1])
        # liveliness changes are posted straight from the Zenoh callback (non-blocking): no worker thread
        # is held for them (thread workers share a small pool with the feeds and the commands)
        self._alive_sub = self.client.subscribe_alive(lambda name, alive: self.post_message(Liveliness({name: alive})))
        self.refresh_alive()

    def on_unmount(self) -> None:
        for sub in self._subs:
            sub.close()
        if self._alive_sub is not None:
            self._alive_sub.close()

    # --- feeds (threads) -----------------------------------------------------------

    @work(thread=True, group="feeds")
    def feed(self, topic: str, sub: Any) -> None:
        while self.is_running:
            try:
                msg = sub.get(timeout=0.5)
            except queue.Empty:
                continue
            except FabricError as err:
                self.call_from_thread(self.log_line, f"[red]bad {topic} message: {escape(str(err))}[/red]")
                continue
            if topic in ("pose", "extrusion", "temps"):
                now = time.monotonic()
                if now - self._last_ui.get(topic, 0.0) < UI_PERIOD_S:
                    continue
                self._last_ui[topic] = now
            self.post_message(Telemetry(topic, msg))

    @work(thread=True, group="alive")
    def refresh_alive(self) -> None:
        self.post_message(Liveliness(self.client.alive(timeout=2.0)))

    # --- messages up -------------------------------------------------------------

    def on_liveliness(self, msg: Liveliness) -> None:
        self.alive.update(msg.alive)
        self.query_one(ServicesPanel).alive = dict(self.alive)

    def on_telemetry(self, msg: Telemetry) -> None:
        if msg.topic == "pose":
            self.query_one(PosePanel).pose = msg.payload
        elif msg.topic == "extrusion":
            self.query_one(ExtrusionPanel).extrusion = msg.payload
        elif msg.topic == "temps":
            self.query_one(ExtrusionPanel).temps = msg.payload
        elif msg.topic == "state":
            self.query_one(StatePanel).state = msg.payload
        elif msg.topic == "events":
            e = msg.payload
            self.log_line(f"#{e.seq} t={e.t_sim_s:.1f}s [b]{escape(e.kind)}[/b] layer {e.layer + 1} line {e.gcode_line}")

    def log_line(self, text: str) -> None:
        self.query_one(RichLog).write(text)

    # --- commands ------------------------------------------------------------------

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id and event.button.id.startswith("cmd-"):
            self.action_command(event.button.id[4:])

    def action_command(self, name: str) -> None:
        self.log_line(f"> {name}")
        self.run_command(name)

    @work(thread=True, group="commands")
    def run_command(self, name: str) -> None:
        _, fn = COMMANDS[name]
        try:
            text = describe(name, fn(self.client))
            self.call_from_thread(self.log_line, f"[green]{name}[/green]: {escape(text)}")
        except FabricError as err:
            self.call_from_thread(self.log_line, f"[red]{name} failed {escape(f'[{err.code}]')}[/red]: "
                                                 f"{escape(err.message)}")
