"""The operator console: the Cell, Jobs, Events and Log screens over one cell link, dialogs for every command."""
from __future__ import annotations

import json
import os
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

from textual import on, work
from textual.app import App
from textual.binding import Binding
from textual.notifications import SeverityLevel
from textual.reactive import reactive

from fabric import schemas as s
from fabric.client import Client
from fabric.extras import missing_extra
from fabric.schemas import states
from fabric.tui.commands import COMMANDS, PRESETS, Preset, describe, refusal, refused_hit
from fabric.tui.format import event_data_text
from fabric.tui.joblist import after_change, console_jobs, not_listed
from fabric.tui.link import CellLink
from fabric.tui.messages import (
    CallRequested,
    CellsListed,
    CollisionChecked,
    HealthReport,
    JobRemoved,
    JobsListed,
    LimitsReady,
    Liveliness,
    ProgramReady,
    Reply,
    ReprintRequested,
    Telemetry,
)
from fabric.tui.screens.cell import CellScreen
from fabric.tui.screens.cells import CellsDialog
from fabric.tui.screens.confirm import ConfirmDialog
from fabric.tui.screens.events import EventsScreen
from fabric.tui.screens.files import FilesScreen
from fabric.tui.screens.help import HelpDialog
from fabric.tui.screens.jobs import JobsScreen
from fabric.tui.screens.log import LogScreen
from fabric.tui.screens.preheat import PreheatDialog
from fabric.tui.screens.report import ReportDialog
from fabric.tui.screens.submit import SubmitChoice, SubmitDialog
from fabric.tui.screens.values import ValuesDialog
from fabric.wire.errors import FabricError

__all__ = ["FabricConsole", "default_state_path"]

GCODE_SUFFIXES = (".gcode", ".gco", ".g", ".nc")
# print events that are also a toast (top right: never over the reply line or a dialog's buttons)
EVENT_TOASTS: dict[str, SeverityLevel] = {"fault": "error", "interlock": "error", "stall": "error",
                                          "interrupted": "error", "stopped": "warning", "finished": "information",
                                          "paused": "warning"}
LOG_LINES = 2000               # replies and events kept for the Log screen


def default_state_path() -> Path:
    """Where the console remembers what it should between runs (the last folder a file was picked in)."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "am-fabric" / "console.json"


class FabricConsole(App):
    """``fabric-tui``. The console's state lives in the reactive attributes below; the screens watch them
    and hand them down to their widgets, and post messages for what the operator asks (handled here with
    ``@on``: no screen knows this class). ``client`` None: no link (the tests set the attributes).
    ``state_path``: a small JSON file of what the console remembers between runs (None: nothing)."""

    CSS_PATH = "console.tcss"
    ENABLE_COMMAND_PALETTE = False
    TITLE = "am-fabric"
    BINDINGS = [
        Binding("ctrl+c", "quit", "quit", show=False, priority=True),
        Binding("1", "switch_mode('cell')", "cell"), Binding("2", "switch_mode('jobs')", "jobs"),
        Binding("3", "switch_mode('events')", "events"), Binding("4", "switch_mode('log')", "log"),
        Binding("5", "switch_mode('files')", "files", show=False),
        Binding("a", "submit", "submit"),
        Binding("s", "command('start')", "start"), Binding("p", "command('pause')", "pause"),
        Binding("r", "command('resume')", "resume"), Binding("x", "command('stop')", "stop"),
        Binding("question_mark", "help", "keys"),
        Binding("o", "command('overrides')", "override", show=False),
        Binding("e", "preheat", "preheat", show=False),
        Binding("q", "quit", "quit", show=False), Binding("f", "command('rtf')", "sim speed", show=False),
        Binding("v", "command('recover')", "recover", show=False),
        Binding("h", "command('home')", "home", show=False),
        Binding("j", "command('jog')", "jog", show=False), Binding("E", "command('extrude')", "extrude", show=False),
        Binding("k", "command('calibrate')", "calibrate", show=False),
        Binding("y", "command('ready')", "ready?", show=False),
        Binding("c", "command('collisions')", "collisions", show=False),
        Binding("w", "command('position')", "position", show=False),
        Binding("t", "command('time')", "time", show=False),
        Binding("g", "cells", "cells", show=False),
    ]

    # the app's data: the screens watch it and set their widgets' own reactives, which repaint those widgets.
    # None of it repaints the app (a repaint of the app is one of the whole screen: with telemetry at 10 Hz a
    # topic, an idle console took 60 % of a core re-rendering every widget)
    client: reactive[Client | None] = reactive(None, repaint=False)    # of the cell followed (None: no link)
    cell: reactive[str] = reactive("")
    station_state: reactive[Any] = reactive(None, always_update=True, repaint=False)
    pose: reactive[Any] = reactive(None, always_update=True, repaint=False)
    extrusion: reactive[Any] = reactive(None, always_update=True, repaint=False)
    temps: reactive[Any] = reactive(None, always_update=True, repaint=False)
    alive: reactive[dict] = reactive(dict, always_update=True, repaint=False)
    degraded: reactive[dict] = reactive(dict, always_update=True, repaint=False)   # service -> reasons ([] = ok)
    toolpath: reactive[Any] = reactive(None, always_update=True, repaint=False)
    collision_hit: reactive[Any] = reactive(None, always_update=True, repaint=False)   # the program's first hit
    limits: reactive[Any] = reactive(None, always_update=True, repaint=False)
    jobs: reactive[list] = reactive(list, always_update=True, repaint=False)
    reply: reactive[Any] = reactive(None, always_update=True, repaint=False)
    last_event: reactive[Any] = reactive(None, always_update=True, repaint=False)
    log_entry: reactive[str] = reactive("", always_update=True, repaint=False)   # the newest line of the log

    def __init__(self, client: Client | None, cell_config: str | None = None, files_root: Path | None = None,
                 wall_clock: Callable[[], float] = time.time,
                 monotonic_clock: Callable[[], float] = time.monotonic, state_path: Path | None = None) -> None:
        super().__init__()
        self.client = client
        self.cell_config = cell_config
        self.state_path = state_path
        self.files_root = files_root or self._remembered_folder() or Path.cwd()
        self.wall_clock, self.monotonic_clock = wall_clock, monotonic_clock
        self.link: CellLink | None = None
        self.log_lines: deque[str] = deque(maxlen=LOG_LINES)
        self._toolpath_id = ""          # the program the toolpath is of
        self._hit_program_id = ""       # the program the collision hit is of
        self._limits_source = ""        # who told the joints' limits shown: "station", "model" or "" (none yet)
        self._queue_changes = 0         # changes of the queue taken (supervisor/queue): a list asked before is stale
        self._removed: set[str] = set()     # jobs removed (by any client): a record of one still on its way is not
                                            # listed again
        self._add_screens()

    def _add_screens(self) -> None:
        """The screens, one mode each. A screen watches the console's reactives; what else it reads (the
        clocks, the log so far) it is handed when it is made."""
        self.add_mode("cell", lambda: CellScreen(self.wall_clock, self.monotonic_clock))
        self.add_mode("jobs", JobsScreen)
        self.add_mode("events", EventsScreen)
        self.add_mode("log", lambda: LogScreen(self.log_lines))
        self.add_mode("files", FilesScreen)

    # --- life ---------------------------------------------------------------------------

    def on_mount(self) -> None:
        self.switch_mode("cell")
        if self.client is not None:
            self._follow(self.client)

    def on_unmount(self) -> None:
        if self.link is not None:
            self.link.close()

    def _follow(self, client: Client) -> None:
        """Follow ``client``'s cell from now on (and forget what the last one showed)."""
        if self.link is not None:
            self.link.close()
        self.client = client
        self.cell = client.keys.cell
        self.sub_title = f"cell {self.cell}"
        self.station_state = self.pose = self.extrusion = self.temps = self.toolpath = self.collision_hit = None
        self.limits, self._limits_source = None, ""
        self.alive, self.degraded, self.jobs, self._toolpath_id, self._hit_program_id = {}, {}, [], "", ""
        self._removed = set()
        self.link = CellLink(client, self.post_message)
        self.link.open()
        self.load_limits()

    def switch_cell(self, name: str) -> None:
        if self.client is not None and name and name != self.cell:
            self._follow(Client(self.client.session, name))
            self.show_reply("cell", True, f"now following cell {name}")

    @work(thread=True, group="limits")
    def load_limits(self) -> None:
        """The joints' limits of the cell followed. Its station tells them (``station/cmd/cell``); while no
        station answers, the cell model of ``--cell-config`` stands in, if one was given (no service else
        knows the arm: a default model could be another arm's, with other limits)."""
        client, cell = self.client, self.cell
        if client is None:
            return
        try:
            info = client.cell_info()
        except FabricError as err:
            if self.cell_config is None:
                return                      # asked again when the station comes up
            self._limits_from_model(cell, err)
            return
        self.post_message(LimitsReady(cell, info.joint_names, info.lower_deg, info.upper_deg, "station"))

    def _limits_from_model(self, cell: str, station_error: FabricError) -> None:
        try:
            from fabric.robot.cell import Cell
            model = Cell.load_or_builtin(self.cell_config).to_dict()["robot"]
        except (FabricError, ModuleNotFoundError) as err:     # the model (Pinocchio) comes with the services extra
            why = err if isinstance(err, FabricError) else missing_extra(err, "the cell model")
            if why is None:
                raise
            self.call_from_thread(self.show_reply, "cell model", False,
                                  f"joint limits unknown: {station_error.message}; {why.message}")
            return
        self.post_message(LimitsReady(cell, model["joint_names"], model["lower_deg"], model["upper_deg"], "model"))

    # --- what the console remembers between runs --------------------------------------------

    def _remembered(self) -> dict[str, Any]:
        if self.state_path is None:
            return {}
        try:
            data = json.loads(self.state_path.read_text())
        except (OSError, ValueError):
            return {}
        return data if isinstance(data, dict) else {}

    def _remembered_folder(self) -> Path | None:
        folder = self._remembered().get("last_folder")
        return Path(folder) if isinstance(folder, str) and Path(folder).is_dir() else None

    def remember_folder(self, folder: Path) -> None:
        """The folder a file was last picked in: the file picker opens there next time (and next run)."""
        self.files_root = folder
        if self.state_path is None:
            return
        try:
            self.state_path.parent.mkdir(parents=True, exist_ok=True)
            self.state_path.write_text(json.dumps({**self._remembered(), "last_folder": str(folder)}))
        except OSError as err:               # not worth more than a line in the log
            self.add_log(f"could not remember the folder ({err})")

    # --- messages up from the cell link ----------------------------------------------------

    @on(Telemetry)
    def _take_telemetry(self, msg: Telemetry) -> None:
        if msg.cell != self.cell:
            return          # from a link closed since
        p = msg.payload
        if msg.topic == "state":
            self.station_state = p
        elif msg.topic == "pose":
            self.pose = p
        elif msg.topic == "extrusion":
            self.extrusion = p
        elif msg.topic == "temps":
            self.temps = p
        elif msg.topic == "events":
            self.last_event = p
            where = f" layer {p.layer + 1}" if p.layer >= 0 else ""
            self.add_log(f"event #{p.seq} {p.kind}{where}  {event_data_text(p.data)}".rstrip())
            severity = EVENT_TOASTS.get(p.kind)
            if severity:
                why = p.data.get("reason", "") if isinstance(p.data, dict) else ""
                self.notify(f"{p.kind} at layer {p.layer + 1}" + (f": {why}" if why else ""),
                            title=f"print {p.kind}", severity=severity, timeout=8)
        elif msg.topic == "jobs":
            self._job_changed(p)
        elif msg.topic == "queue":
            self._queue_changed(p)

    def _queue_changed(self, change: s.QueueChange) -> None:
        """A job submitted, removed or moved, by this console or any other client: the list shows it at once (a
        removal has no record on ``jobs`` to say it, a move changes no record). A list asked before this change
        is asked again when it comes (it may not show it)."""
        self._queue_changes += 1
        if change.kind == "removed":
            self._removed.add(change.job_id)
        self.jobs = after_change(self.jobs, change)
        self.add_log(f"queue: job {change.job_id} {change.kind}")
        if not_listed(self.jobs, change):
            self.refresh_jobs()        # a job submitted: its record is on its way, the list read says it too

    def _job_changed(self, rec: s.JobRecord) -> None:
        if rec.job_id in self._removed:
            return                     # sent before its removal, come after it
        jobs = list(self.jobs)
        for i, old in enumerate(jobs):
            if old.job_id == rec.job_id:
                now, before = states.PrintJob(rec.state), states.PrintJob(old.state)
                if now is states.PrintJob.FAILED and before is not states.PrintJob.FAILED:
                    self.notify(f"{rec.filename}: {rec.reason or rec.stage}", title=f"job {rec.job_id} failed",
                                severity="error", timeout=10)
                    self.add_log(f"job {rec.job_id} failed: {rec.reason or rec.stage}")
                jobs[i] = rec
                self.jobs = jobs
                return
        self.jobs = jobs + [rec]
        self.refresh_jobs()        # a new job: the supervisor knows its place in the queue

    @on(Liveliness)
    def _take_liveliness(self, msg: Liveliness) -> None:
        if msg.cell == self.cell:
            came = msg.alive.get("station") and not self.alive.get("station")
            self.alive = {**self.alive, **msg.alive}
            if came and self._limits_source != "station":     # a station (again): it tells its cell's arm
                self.load_limits()

    @on(HealthReport)
    def _take_health(self, msg: HealthReport) -> None:
        if msg.cell == self.cell:
            self.degraded = dict(msg.degraded)

    @on(JobsListed)
    def _take_jobs(self, msg: JobsListed) -> None:
        if msg.cell != self.cell:
            return
        if msg.changes_seen < self._queue_changes:
            self.refresh_jobs()        # asked before the queue last changed: it may undo the change on the screen
            return
        self.jobs = [r for r in msg.jobs if r.job_id not in self._removed]

    @on(ProgramReady)
    def _take_program(self, msg: ProgramReady) -> None:
        if msg.cell == self.cell:
            self.toolpath, self._toolpath_id = msg.toolpath, msg.program_id
            if self.collision_hit is not None and msg.program_id != self._hit_program_id:
                self.collision_hit = None          # a hit of the program loaded before

    @on(CollisionChecked)
    def _take_collision_report(self, msg: CollisionChecked) -> None:
        """A collision report: its first hit is marked on the layer view, a collision-free one clears the mark.
        A report on a program other than the one shown (it changed meanwhile) marks nothing."""
        if msg.cell != self.cell:
            return
        if self._toolpath_id and msg.program_id and msg.program_id != self._toolpath_id:
            return
        hit = None if msg.report.collision_free else msg.report.first_hit
        self._hit_program_id = msg.program_id or self._toolpath_id
        self.collision_hit = hit

    @on(LimitsReady)
    def _take_limits(self, msg: LimitsReady) -> None:
        if msg.cell == self.cell:
            self.limits = (msg.lower_deg, msg.upper_deg)
            self._limits_source = msg.source

    @on(Reply)
    def _take_reply(self, msg: Reply) -> None:
        self.show_reply(msg.command, msg.ok, msg.text, msg.severity)
        if msg.report:
            self.push_screen(ReportDialog(msg.command, msg.report))

    @on(CellsListed)
    def _offer_cells(self, msg: CellsListed) -> None:
        def chosen(name: str | None) -> None:
            if name:
                self.switch_cell(name)

        self.push_screen(CellsDialog(msg.cells, self.cell), chosen)

    def show_reply(self, command: str, ok: bool, text: str, severity: SeverityLevel | Literal[""] = "") -> None:
        """The reply stays on the reply line (every screen has one) and goes to the log; no toast, which would
        cover the reply line or a dialog's buttons."""
        self.reply = (command, ok, text)
        self.add_log(f"{command}: {'' if ok else 'REFUSED '}{text}")

    def add_log(self, line: str) -> None:
        stamped = f"{time.strftime('%H:%M:%S', time.localtime(self.wall_clock()))} {line}"
        self.log_lines.append(stamped)
        self.log_entry = stamped

    # --- messages up from the screens --------------------------------------------------------

    @on(CallRequested)
    def _run_requested_call(self, msg: CallRequested) -> None:
        self.run_call(msg.label, msg.call, msg.refresh_jobs)

    @on(JobRemoved)
    def _forget_job(self, msg: JobRemoved) -> None:
        """A job removed: off the screens at once (the list read next confirms it)."""
        self._removed.add(msg.job_id)
        self.jobs = [r for r in self.jobs if r.job_id != msg.job_id]

    @on(ReprintRequested)
    def _reprint_requested(self, msg: ReprintRequested) -> None:
        self.reprint(msg.record)

    # --- commands ---------------------------------------------------------------------------

    def action_command(self, name: str) -> None:
        cmd = COMMANDS[name]
        st = self.station_state
        why = refusal(cmd, states.Station(st.state) if st is not None else None)
        if why:                                  # not asked first only to be refused after
            self.show_reply(name, False, why)
            return

        def ask_values(_: object = True) -> None:
            if not cmd.asks:
                self.run_command(name, {})
                return
            current = self._current_values()
            self.push_screen(ValuesDialog(cmd.label.capitalize(), cmd.asks, current), entered)

        def entered(values: dict[str, Any] | None) -> None:
            if values is not None:
                self.run_command(name, values)

        def confirmed(yes: bool | None) -> None:
            if yes:
                ask_values()

        if cmd.confirm:
            self.push_screen(ConfirmDialog(cmd.label.capitalize(), cmd.confirm), confirmed)
        else:
            ask_values()

    def _current_values(self) -> dict[str, float]:
        st, t = self.station_state, self.temps
        out: dict[str, float] = {}
        if st is not None:
            out.update(speed_r=st.speed_r, flow_r=st.flow_r, rtf=st.rtf)
        if t is not None:
            out.update(nozzle_c=t.nozzle_target_c, bed_c=t.bed_target_c)
        return out

    @work(thread=True, group="commands")
    def run_command(self, name: str, values: dict[str, Any]) -> None:
        cmd = COMMANDS[name]
        if self.client is None:
            self.post_message(Reply(name, False, "not connected to a cell"))
            return
        cell, st = self.client.keys.cell, self.station_state
        program_id = st.program_id if st is not None else ""     # what a collision report will be of
        try:
            result = cmd.call(self.client, values)
        except FabricError as err:
            self.post_message(Reply(name, False, f"[{err.code}] {err.message}"))
            hit = refused_hit(err)             # a live move refused by its check: marked like a report's hit
            if hit is not None:
                self.post_message(CollisionChecked(cell, program_id, s.CollisionReport(
                    collision_free=False, checked_configs=0, min_distance_mm=0.0, first_hit=hit)))
            return
        if isinstance(result, s.CollisionReport):
            self.post_message(CollisionChecked(cell, program_id, result))
        line, report = describe(name, result)
        severity: SeverityLevel | Literal[""] = "error" if isinstance(result, s.CollisionReport) \
            and not result.collision_free else ""
        if isinstance(result, s.ReadyReport) and not result.ready:
            severity = "warning"
        self.post_message(Reply(name, True, line, report if cmd.report else "", severity))

    def action_preheat(self) -> None:
        def chosen(preset: Preset | None) -> None:
            if preset is not None:
                self.run_command("overrides", {"nozzle_c": preset.nozzle_c, "bed_c": preset.bed_c})
        self.push_screen(PreheatDialog(PRESETS), chosen)

    @work(thread=True, group="commands")
    def run_call(self, label: str, fn: Callable[[Client], Any], refresh_jobs: bool = False) -> None:
        """A job command (``fn(client)``), answered on the reply line; ``refresh_jobs``: read the job list after
        (the queue's changes come on ``supervisor/queue``, the records' on ``jobs``: the list read confirms them).
        A ``job move``'s own list is not taken: it is the queue's first page, not the jobs the console lists."""
        if self.client is None:
            return
        try:
            result = fn(self.client)
        except FabricError as err:
            self.post_message(Reply(label, False, f"[{err.code}] {err.message}"))
            return
        text = getattr(result, "message", "") or "ok"
        self.post_message(Reply(label, True, text))
        if refresh_jobs:
            self._list_jobs()

    @work(thread=True, group="jobs")
    def refresh_jobs(self) -> None:
        self._list_jobs()

    def _list_jobs(self) -> None:
        """Ask the supervisor for the job list (blocking: from a thread)."""
        client, seen = self.client, self._queue_changes
        if client is None:
            return
        try:
            self.post_message(JobsListed(client.keys.cell, console_jobs(client), seen))
        except FabricError as err:
            self.post_message(Reply("jobs", False, f"[{err.code}] {err.message}"))

    # --- jobs, cells, help ---------------------------------------------------------------------

    def action_submit(self) -> None:
        self.open_submit()

    @work(thread=True, group="submit")
    def open_submit(self) -> None:
        """Ask the slicer what it offers, then show the dialog."""
        backends: dict[str, str] = {"builtin": ""}
        profiles: list[str] = []
        if self.client is not None:
            try:
                b = self.client.backends()
                backends, profiles = b.backends, b.profiles
            except FabricError as err:
                self.post_message(Reply("submit", False, f"slicer: {err.message} (G-code still works)"))
        self.call_from_thread(self.push_screen, SubmitDialog(self.files_root, backends, profiles),
                              self._submit_chosen)

    def _submit_chosen(self, choice: SubmitChoice | None) -> None:
        if choice is not None:
            self.remember_folder(choice.path.parent)
            self.submit(choice)

    @work(thread=True, group="submit")
    def submit(self, choice: SubmitChoice) -> None:
        if self.client is None:
            return
        source = "gcode" if choice.path.suffix.lower() in GCODE_SUFFIXES else "model"
        try:
            req = s.JobSubmit(model=choice.path.read_bytes(), filename=choice.path.name, source=source,
                              profile=choice.profile, backend=choice.backend, start=choice.start, rtf=choice.rtf,
                              layers=choice.layers if source == "model" else "planar")
            acc = self.client.submit(req)
        except (FabricError, OSError) as err:
            self.post_message(Reply("submit", False, getattr(err, "message", str(err))))
            return
        self.post_message(Reply("submit", True, f"job {acc.job_id} queued: {choice.path.name}"))
        self._list_jobs()

    @work(thread=True, group="submit")
    def reprint(self, rec: s.JobRecord) -> None:
        """Print a job's file again, as a new job with its settings (the supervisor keeps the file it was
        submitted with as long as its store has room)."""
        if self.client is None:
            return
        try:
            art = self.client.artifact("supervisor", rec.model_id, timeout=30.0)
            acc = self.client.submit(s.JobSubmit(model=art.data, filename=rec.filename, source=rec.source,
                                                 profile=rec.profile or "taz-pla-medium",
                                                 backend=rec.backend or "builtin", overrides=dict(rec.overrides),
                                                 start=rec.start, rtf=rec.rtf,
                                                 filament_diameter_mm=rec.filament_diameter_mm, layers=rec.layers))
        except FabricError as err:
            why = "the file is no longer kept: submit it again (a)" if err.code == "not_found" else err.message
            self.post_message(Reply("print again", False, f"job {rec.job_id}: {why}"))
            return
        self.post_message(Reply("print again", True, f"job {acc.job_id} queued: {rec.filename} again "
                                                     f"(as job {rec.job_id})"))
        self._list_jobs()

    @work(thread=True, group="cells")
    def action_cells(self) -> None:
        if self.client is not None:
            self.post_message(CellsListed(self.client.cells(timeout=2.0)))

    def action_help(self) -> None:
        self.push_screen(HelpDialog())
