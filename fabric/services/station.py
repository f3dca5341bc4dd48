"""Station service: the digital twin of the cell, run in simulated time, with the paper's commands.

The twin (``fabric.sim.twin.Twin``) is pure simulation; this module gives it a
clock and the fabric. A simulation thread advances the twin by
``dt_wall * rtf`` each tick (``rtf`` 1 = real time; 0 = as fast as possible,
advancing in chunks sized to keep each tick near ``TICK_S`` of wall time).
Simulated time is exact whatever the stepping, because the twin's timeline is
analytic. Every twin event is published on the lossless ``events`` topic and
kept for the ``events`` query; pose is published at a fixed wall-clock rate
(latest value wins), extrusion and temperatures on every change of their
discrete part (extruder on/off, flow, layer; set points) and otherwise at a
lower rate (:mod:`fabric.services.telemetry_gate`); state on every change.

Every change of the twin happens on one thread, the clock's: a command is a
step of the station's writer (:mod:`fabric.server.writer`), run between two
ticks, through one mechanism (:class:`~fabric.services.station_commands.CommandRunner`):
a change, or a checked change whose moves are certified against the part on the
plate between its plan and its act, and which acts only if the twin has not
changed meanwhile; the mechanism takes the checkpoint. The twin and the
station's record of it are :class:`~fabric.server.writer.Owned` by the writer:
another thread that touches them raises. Reads (``state``, ``time``, ``ready``)
are steps too, so they see one consistent twin; ``position`` is a snapshot the
clock keeps. Commands of other modules (``jog``, ``extrude``) register
themselves through :meth:`StationService.register_command`.

The station is durable (:mod:`fabric.store.journal`): each tick's events and
the simulated time reached are written before they are published, and the
twin is checkpointed at a bounded cadence and after every command. A station
killed mid-print comes back ``interrupted`` at the spot where it was lost,
with its program, deposit record and event numbering; ``recover`` goes on.
A tick that comes much later than due (the process was frozen or starved)
never makes simulated time jump: the stall is recorded as an event, and a
print is interrupted there when the stall was long enough for the fabric to
report the station gone.
"""
from __future__ import annotations

import argparse
import sys
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from fabric import schemas as s
from fabric.client import Client
from fabric.drivers.address import open_controller, robot_address
from fabric.drivers.controller import Controller
from fabric.programs import content_id, program_from_artifact
from fabric.robot.cell import Cell
from fabric.robot.frames import T_to_xyzrpy
from fabric.server.disk import require_room
from fabric.server.health import Backoff
from fabric.server.service import Service
from fabric.server.writer import Owned, Writer
from fabric.services.readiness import ReadyFacts, print_temp_c, ready_report
from fabric.services.station_commands import Check, CommandRunner, Move, Planned, RestOfProgram
from fabric.services.station_manual import ManualCommands
from fabric.services.station_messages import StationMessages
from fabric.services.station_plate import PlateGuard
from fabric.services.station_robot import JOINT_TIME_R, RobotLink
from fabric.sim.deposition import Deposition
from fabric.sim.moves import RestartPath
from fabric.sim.twin import EVENT_KINDS, Twin
from fabric.store.journal import DEFAULT_CHECKPOINT_PERIOD_S, StationJournal, StationMeta
from fabric.store.station import StationStore
from fabric.wire import codec
from fabric.wire.config import add_cell_argument, service_data_dir
from fabric.wire.errors import CollisionError, FabricError, NotFound, StateError, ValidationError
from fabric.wire.keys import endpoints_of

__all__ = ["StationService", "build", "add_arguments"]

TICK_S = 0.02
STATE_PERIOD_S = 0.5          # state also re-published at this period (progress)
GIL_SWITCH_S = 0.0005         # a command's thread waits at most this long for the clock thread's interpreter lock
STALL_S = 0.5                 # a tick this late: the process was frozen or starved (time is held, noted)
STALL_INTERRUPT_S = 2.0       # this late, the fabric has reported the station gone: a print is interrupted
CLOCK_HEALTHY_S = 30.0        # a clock that failed and has run this long since is healthy again
SNAPSHOTS = ("position", "cell", "health")      # served from a kept reply, not by a handler


class StationService(Service):
    name = "station"
    # the writer's (the clock thread's): read or changed in its steps only
    twin: Owned[Twin] = Owned()
    meta: Owned[StationMeta] = Owned()
    collision_report: Owned[s.CollisionReport | None] = Owned()

    def __init__(self, session: zenoh.Session, cell_id: str, cell: Cell, pose_hz: float = 50.0,
                 data_dir: Path | None = None, checkpoint_s: float = DEFAULT_CHECKPOINT_PERIOD_S,
                 controller: Controller | None = None) -> None:
        super().__init__(session, cell_id, data_dir)
        self.cell = cell
        self.client = Client(session, cell_id)
        self.pose_period_s = 1.0 / pose_hz
        self.writer = Writer(self.name)             # the one thread that touches the twin: the clock's
        self.meta = StationMeta()
        self.collision_report: s.CollisionReport | None = None
        self.journal = StationJournal(StationStore(self.data_dir / "station.sqlite"), self.artifacts, checkpoint_s)
        self.twin, self._backlog = self._restore()
        self.clock_stop = threading.Event()         # set first on close: the clock thread ends
        self.msgs = StationMessages(self.twin, self.meta)
        self.plate = PlateGuard(self.twin, self.meta)          # the part on the plate, and its rules
        self.commands = CommandRunner(self.writer, self._stamp, self._checkpoint, lambda move: self.certify(move),
                                      lambda: self.twin.state)
        # the robot the station drives, if any: the twin is its shadow (fabric.services.station_robot)
        self.robot = None if controller is None else RobotLink(controller, self.twin, cell.deviation_bound_mm,
                                                                 self.log)
        if self.robot is not None:
            self.twin.time_for_robot(JOINT_TIME_R)   # the robot's controller follows these (station_robot)
            self.msgs.follow_robot(self.robot)
            self.pub_deviation = self.publisher("deviation")
            self.commands.motion_gate = self.robot.gate
        self._last_state: tuple = ()
        self._last_state_s = 0.0
        self.pub_pose = self.publisher("pose")
        self.pub_extrusion = self.publisher("extrusion")
        self.pub_temps = self.publisher("temps")
        self.pub_state = self.publisher("state", lossless=True)
        self.pub_events = self.publisher("events", lossless=True)
        self._position = codec.encode(self.msgs.pose())    # the twin's pose now, encoded
        self.handle_snapshot("position", lambda: self._position)
        cell_info = codec.encode(cell_info_of(cell))              # constant for the process's life
        self.handle_snapshot("cell", lambda: cell_info)
        for ep in endpoints_of(self.name):
            handler = getattr(self, f"on_{ep.command}", None)
            if ep.command not in SNAPSHOTS and handler is not None:
                self.handle(ep.command, handler)
        self.manual = ManualCommands(self)          # jog, extrude: they register themselves

    # The meta's fields, as the rest of this module reads them.
    program_id = property(lambda self: self.meta.program_id)
    job_id = property(lambda self: self.meta.job_id)
    layers_total = property(lambda self: self.meta.layers_total)
    rtf = property(lambda self: self.meta.rtf)

    def start(self) -> None:
        # the clock thread runs Python for up to a tick; by default a command's thread could wait 5 ms for
        # the interpreter lock before being let in (the station is its own process: this is its setting)
        sys.setswitchinterval(GIL_SWITCH_S)
        if self.robot is not None:                   # before the clock runs: this thread is the twin's still
            try:
                self.robot.connect(self.twin)
            except FabricError as err:
                self.log.error("%s (the station serves; a motion command connects again)", err.message)
        super().start()
        self._thread = threading.Thread(target=self._sim_loop, name="station:clock", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self.clock_stop.set()                        # the clock stops publishing before anything is undeclared
        if hasattr(self, "_thread"):                 # not there when start was refused
            self._thread.join(timeout=5.0)
        self.writer.close()
        if self.robot is not None:                   # the clock has stopped feeding it: stop the robot
            self.robot.close()
        super().close()
        self.journal.checkpoint(self.twin, self.meta, force=True)     # the writer has ended: this thread may
        self.journal.store.close()

    def _restore(self) -> tuple[Twin, list]:
        """The twin as the last run left it (interrupted if it was printing), or a fresh one."""
        try:
            restored = self.journal.restore(self.cell)
        except FabricError as err:
            self.log.error("could not restore the last checkpoint (%s: %s): starting with a faulted twin",
                           err.code, err.message)
            twin = Twin(self.cell)
            twin.number_events_after(self.journal.last_seq())
            twin.trip(f"could not restore the last run ({err.message}): the robot's pose is unknown")
            return twin, []
        if restored is None:
            twin = Twin(self.cell)
            twin.number_events_after(self.journal.last_seq())
            return twin, []
        self.meta = restored.meta
        return restored.twin, restored.events

    # --- the public surface commands are built on (fabric.services.station_commands) ---------

    def register_command(self, command: str, handler: Callable[[Any], Any]) -> None:
        """Serve station endpoint ``command`` (declared in ``fabric.wire.keys``) with ``handler``: how a
        command of another module joins the station. Its changes go through :attr:`commands`."""
        self.handle(command, handler)

    def ack(self, message: str) -> s.Ack:
        """A command's acknowledgement, with the state it left the station in (on the writer)."""
        return s.Ack(ok=True, message=message, state=self.twin.state)

    def certify(self, check: Check) -> None:
        """What the station is about to make the robot do, certified by the collision service against the beads
        the twin has actually laid (it asks ``station/beads`` for them, and keeps them between checks: a
        million beads cross once, not with every move). A move: the nozzle tip may touch the last bead's layer
        and the one under it (where an interrupted print left it); on a ``descent`` the layer it goes down onto
        and the one under, as when printing it. The rest of a program (a restart, a recovery): every move to
        its return home, and none of its beads into the part. Raises CollisionError on a hit, naming it and
        what would be accepted. Runs outside the writer."""
        if isinstance(check, RestOfProgram):
            self._certify_rest(check)
            return
        move = check
        q_down, down_layer = move.descent if move.descent is not None else (None, -1)
        report = self.client.check(s.CollisionRequest(
            q_from_deg=np.degrees(move.q_from_rad).tolist(), q_to_deg=np.degrees(move.q_to_rad).tolist(),
            beads="station", tip_layer=-2, vel_r=float(move.vel_r), kind=move.kind,
            q_down_deg=np.degrees(q_down).tolist() if q_down is not None else None, down_layer=down_layer))
        hit = report.first_hit
        if hit is not None:
            then = f"; {move.accepted}" if move.accepted else ""
            raise CollisionError(f"{move.what} would collide: {hit.message or f'{hit.body_a} <-> {hit.body_b}'}{then}",
                                 accepted=move.accepted, **{k: v for k, v in s.to_plain(hit).items() if k != "message"})

    def _certify_rest(self, rest: RestOfProgram) -> None:
        report = self.client.check(s.CollisionRequest(
            program_id=rest.program_id, from_row=rest.from_row, beads="station",
            q_start_deg=np.degrees(rest.q_start_rad).tolist()))
        hit = report.first_hit
        if hit is not None:
            then = f"; {rest.accepted}" if rest.accepted else ""
            raise CollisionError(f"{rest.what} would collide: {hit.message or f'{hit.body_a} <-> {hit.body_b}'}{then}",
                                 accepted=rest.accepted, **{k: v for k, v in s.to_plain(hit).items() if k != "message"})

    def rest_of_program(self, from_row: int, q_start_rad: np.ndarray, what: str) -> RestOfProgram:
        """The loaded program from ``from_row``, for a checked command's plan (on the writer)."""
        return RestOfProgram(self.meta.program_id, int(from_row), np.asarray(q_start_rad, dtype=float), what,
                             self.plate.going_on())

    def move(self, q_from_rad: np.ndarray, q_to_rad: np.ndarray, what: str, kind: str,
             descent: tuple[np.ndarray, int] | None = None, accepted: str = "") -> Move:
        """A joint move at the twin's home speed, for a checked command's plan (on the writer)."""
        return Move(np.asarray(q_from_rad, dtype=float), np.asarray(q_to_rad, dtype=float), what, kind,
                    float(self.twin.config.home_vel_r), descent, accepted)

    def _stamp(self) -> tuple:
        """What a checked command's act compares with its plan's (besides the change counter): the same state,
        the robot where it was."""
        return (self.twin.state, np.round(self.twin.pose().q_rad, 6).tobytes())

    def _checkpoint(self) -> None:
        """After a command changed the twin (on the writer, by the command runner only): checkpoint it, and
        bring the ``position`` snapshot up to date (so ``position`` after the reply sees e.g. a new work
        object)."""
        self.journal.checkpoint(self.twin, self.meta, force=True)
        self._position = codec.encode(self.msgs.pose())

    # --- simulation clock ------------------------------------------------------

    def _sim_loop(self) -> None:
        """Run the clock. A failure inside it faults the print, marks the station degraded and is logged; a
        clock that keeps failing backs off (up to seconds between tries) instead of spinning."""
        backoff = Backoff(healthy_s=CLOCK_HEALTHY_S)
        while not self.clock_stop.is_set():
            try:
                self._run_clock(backoff)
            except Exception as exc:  # noqa: BLE001 - a bug or a full disk: fault the print, say why, try later
                pause_s = backoff.failed()
                why = f"{type(exc).__name__}: {exc}"
                self.health.degrade("clock", f"{why} (failed {backoff.failures}x; next try in {pause_s:.2f} s)")
                self.log.error("simulation failed (%d in a row; next try in %.2f s):\n%s", backoff.failures,
                               pause_s, traceback.format_exc())
                if self.twin.state.in_print:
                    self.twin.trip(f"station error: {why}")
                resume_at = time.monotonic() + pause_s
                while not self.clock_stop.is_set() and time.monotonic() < resume_at:   # commands still run
                    self.writer.run_pending(min(TICK_S, max(resume_at - time.monotonic(), 0.0)))

    def _run_clock(self, backoff: Backoff) -> None:
        last = time.monotonic()
        next_pose = last
        chunk_s = 1.0
        backlog, self._backlog = self._backlog, []
        while not self.clock_stop.is_set():
            self.writer.run_pending(max(0.0, min(TICK_S, next_pose - time.monotonic())))
            if self.clock_stop.is_set():
                return
            now = time.monotonic()
            if now - last > STALL_S:
                self._stalled(now - last)
                last = now
            if self.robot is not None:                 # real time, as far as the robot had its path
                events = self.twin.advance(self.robot.advance_s(now, last))
            elif self.rtf > 0 or not self.twin.state.printing:
                events = self.twin.advance((now - last) * (self.rtf if self.rtf > 0 else 1.0))
            else:  # as fast as possible: whole chunks until this tick's wall budget is spent
                events, t0 = [], time.monotonic()
                while self.twin.state.printing and time.monotonic() - t0 < TICK_S:
                    events += self.twin.advance(chunk_s)
                spent = time.monotonic() - t0
                chunk_s = float(np.clip(chunk_s * (TICK_S / max(spent, 1e-4)) ** 0.5, 0.05, 600.0))
            last = now
            msgs = [self.msgs.event(ev) for ev in backlog + events]
            backlog = []
            ext_now = self.twin.extrusion()
            if self.robot is not None:
                self._follow_robot(now, ext_now)
            self.plate.track(ext_now.extruded_mm3)
            key = self.msgs.state_key(ext_now)
            state_due = key != self._last_state or now - self._last_state_s >= STATE_PERIOD_S
            state = self.msgs.state(ext_now) if state_due else None       # built only when published
            pose_due = now >= next_pose
            # the pose now: the position reply from this tick on, and the pose sample when one is due
            position = self._position = codec.encode(self.msgs.pose(sample=pose_due))
            ext = self.msgs.extrusion_due(now, ext_now) if pose_due else None
            temps = self.msgs.temps_due(now) if pose_due else None
            at_rest = not self.twin.state.printing and not self.twin.moving
            self.journal.record_tick(msgs, self.twin.t_sim_s, at_rest)      # written before it is published
            self.journal.checkpoint(self.twin, self.meta, force=key[:4] != self._last_state[:4])
            for m in msgs:
                self.pub_events.send(m)
            if state is not None:
                self._last_state, self._last_state_s = key, now
                self.pub_state.send(state)
            if pose_due:
                next_pose = max(next_pose + self.pose_period_s, now)
                self.pub_pose.send_encoded(position)
            if pose_due and self.robot is not None:
                self.msgs.seq_deviation += 1
                self.pub_deviation.send(self.robot.deviation_msg(self.msgs.seq_deviation, self.twin.t_sim_s))
            if ext is not None:
                self.pub_extrusion.send(ext)
            if temps is not None:
                self.pub_temps.send(temps)
            if backoff.failures and backoff.recovered():       # a clock that failed has run well since
                self.health.clear("clock")
                backoff.failures = 0

    def _follow_robot(self, now: float, ext: Any) -> None:
        """The robot's tick (fabric.services.station_robot): a fault interrupts the print, a TCP off its path
        pauses it."""
        assert self.robot is not None
        action = self.robot.tick(self.twin, now, int(ext.row), int(ext.gcode_line), bool(ext.on))
        if action is None:
            return
        self.log.warning("%s", action.reason)
        if action.kind == "interrupt":
            self.robot.halt()
            self.twin.interrupt(action.reason)
        elif action.kind == "pause":
            self.twin.pause(action.reason)

    def _stalled(self, gap_s: float) -> None:
        """The tick came ``gap_s`` late: simulated time does not jump (it is held, and the stall noted).
        Past ``STALL_INTERRUPT_S`` (twice the default link lease: the fabric has reported the station
        gone, and its clients may have acted on that) a running print is interrupted; a shorter hiccup
        of a loaded machine is not."""
        why = f"the station stalled for {gap_s:.1f} s (process frozen or starved)"
        self.log.warning("%s: simulated time held at %.3f s", why, self.twin.t_sim_s)
        self.twin.note("stall", {"stalled_s": round(gap_s, 3), "state": self.twin.state})
        if gap_s >= STALL_INTERRUPT_S and self.twin.state.in_print:
            self.twin.interrupt(why + ": recover to go on")

    # --- the paper's commands ----------------------------------------------------
    # Each is a change or a checked change of self.commands (fabric.services.station_commands): the runner
    # takes the checkpoint; a refusal raised in a plan or an act changes nothing.

    def on_home(self, _: s.Empty) -> s.Ack:
        def plan() -> Planned[None]:
            if self.twin.state.in_print:
                raise StateError(f"cannot go home while {self.twin.state}; stop first",
                                 state=self.twin.state, command="home")
            return Planned([self.move(self.twin.pose().q_rad, self.cell.home_q_rad, "the move home", "home")],
                           None, "the move home")

        def act(_: Planned[None]) -> s.Ack:
            self.twin.go_home()
            return self.ack("moving home (collision-checked)")
        return self.commands.checked("home", plan, act)

    def on_load(self, req: s.LoadRequest) -> s.TimeInfo:
        art = self.client.artifact("planner", req.program_id)       # fetched and decoded outside the writer
        program = program_from_artifact(art)
        require_room(self.data_dir, len(art.data), self.name, "keeping the program")
        self.artifacts.put(art)        # on disk before the twin takes it: a full disk leaves the station as it was

        def act() -> s.TimeInfo:
            if self.twin.state.in_print:
                raise StateError(f"cannot load while {self.twin.state}", state=self.twin.state, command="load")
            self.plate.refuse_load()
            self.twin.load(program)
            self.journal.keep_program(art)
            self.meta.program_id, self.meta.job_id = req.program_id, req.job_id
            self.meta.layers_total = int(program.layer.max() + 1) if len(program) else 0
            self.meta.planned_mm3 = program.deposited_volume_mm3()
            self.collision_report = None
            return self._time_msg()
        return self.commands.change(act)

    def on_start(self, req: s.StartRequest) -> s.Ack:
        layer = req.from_layer if req.from_layer >= 0 else None

        def where(goes_on: bool) -> str:
            if layer is None:
                return ""
            on = ", where the part ends" if goes_on else ""
            return f" from layer {layer + 1}{on} (heating, then the move above it)"

        def plan() -> Planned[bool]:
            self._real_time("start", req.rtf)
            self.plate.refuse_start("start", layer)
            if layer is None:                          # from the beginning: the program was certified when planned
                return Planned([], False)
            path = self._restart_path(layer, "start")
            what = f"the move to layer {layer + 1}"
            row = path.row
            goes_on = row > self.twin.moves.layer_start_row(layer)       # the part has some of this layer
            return Planned([self.move(path.q_from_rad, path.q_above_rad, what, "restart",
                                      descent=(path.q_down_rad, layer), accepted=self.plate.going_on()),
                            self.rest_of_program(row, path.q_down_rad, f"the print from layer {layer + 1}")],
                           goes_on, what)

        def act(planned: Planned[bool]) -> s.Ack:
            self.plate.refuse_start("start", layer)
            self.twin.start(from_layer=layer)
            self._set_rtf(req.rtf)
            return self.ack(f"printing{where(planned.data)} at {self._rtf_text()}")
        return self.commands.checked("start", plan, act)

    def _restart_path(self, layer: int, command: str) -> RestartPath:
        """The motion a restart at ``layer`` makes before it prints, as the twin will queue it: the joint move
        above the layer's first point and the straight descent onto it (a step of the writer). Refused when
        nothing is loaded or the program has no such layer."""
        if self.twin.program is None:
            raise StateError("no program loaded", state=self.twin.state, command=command)
        return self.twin.moves.restart_path(self.twin.restart_point(layer))

    def _set_rtf(self, rtf: float | None) -> None:
        """Take the request's real-time factor, if it gives one (nil keeps the current one)."""
        if rtf is not None:
            self.meta.rtf = rtf

    def _real_time(self, command: str, rtf: float | None) -> None:
        """(In a step.) A station driving a robot runs in real time: another factor is refused, first."""
        if self.robot is not None and rtf is not None and rtf != 1.0:
            raise StateError(f"{command} refused: the station drives robot {self.robot.address}, which runs in "
                             f"real time (rtf 1), not {rtf:g}", state=self.twin.state, command=command)

    def _rtf_text(self) -> str:
        return "max speed" if self.meta.rtf == 0 else f"{self.meta.rtf:g}x real time"

    def on_pause(self, _: s.Empty) -> s.Ack:
        def act() -> s.Ack:
            self.twin.pause()
            return self.ack("paused: extruder off, retracted, lifted clear")
        return self.commands.change(act)

    def on_resume(self, req: s.StartRequest) -> s.Ack:
        def act() -> s.Ack:
            self._real_time("resume", req.rtf)
            if self.robot is not None:
                self.robot.gate("resume")
            self.twin.resume()
            self._set_rtf(req.rtf)
            return self.ack(f"resuming at the paused spot at {self._rtf_text()}")
        return self.commands.change(act)

    def on_recover(self, req: s.StartRequest) -> s.Ack:
        layer = req.from_layer if req.from_layer >= 0 else None
        where = "the interrupted spot" if layer is None else f"layer {layer + 1}"
        what = f"the move back to {where}"
        reconnected = self._reconnect_robot()

        def plan() -> Planned[bool]:
            self._real_time("recover", req.rtf)
            move = self.twin.recovery_move(layer)
            if move is None and reconnected:           # the robot was the only thing to recover
                return Planned([], True, what)
            if move is None:
                raise StateError(f"nothing to recover while {self.twin.state}", state=self.twin.state,
                                 command="recover")
            if layer is None:                          # back to the interrupted spot, then the rest from there
                row = self.twin.resume_row
                assert row is not None, "recovery_move answers only when a spot is kept"
                return Planned([self.move(*move, what, "recover"),
                                self.rest_of_program(row, move[1], "the print from the interrupted spot")],
                               False, what)
            self.plate.refuse_in_the_air("recover", layer)
            path = self._restart_path(layer, "recover")    # from a layer: the move above it, then down
            row = path.row
            return Planned([self.move(path.q_from_rad, path.q_above_rad, what, "recover",
                                      descent=(path.q_down_rad, layer), accepted="or recover at the interrupted spot"),
                            self.rest_of_program(row, path.q_down_rad, f"the print from layer {layer + 1}")],
                           False, what)

        def act(planned: Planned[bool]) -> s.Ack:
            if planned.data:
                assert self.robot is not None
                return self.ack(f"robot {self.robot.address} connected again, its errors cleared; it follows the "
                                f"twin (nothing else to recover while {self.twin.state})")
            self.twin.recover(from_layer=layer)
            self._set_rtf(req.rtf)
            return self.ack(f"recovering: back to {where} (collision-checked), then going on at {self._rtf_text()}")
        return self.commands.checked("recover", plan, act)

    def _reconnect_robot(self) -> bool:
        """Before recover: a robot that is not ready is connected again (this thread: up to the connect
        deadline) and follows the twin again (a step: the twin at rest stands where it stands). False when
        there is no robot or it was ready; a RobotError says why it could not be."""
        if self.robot is None or self.robot.ready:
            return False
        self.robot.reconnect()
        robot = self.robot
        self.commands.change(lambda: robot.attach(self.twin))
        return True

    def on_stop(self, _: s.Empty) -> s.Ack:
        def act() -> s.Ack:
            self.twin.stop()
            return self.ack("stopped: extruder off, moved clear; deposit kept on record")
        return self.commands.change(act)

    def on_clear_plate(self, _: s.Empty) -> s.Ack:
        def act() -> s.Ack:
            what = self.plate.clear()
            if not what:
                return self.ack("the plate was clear already (noted: a job waiting for it goes on)")
            return self.ack(f"plate clear: {what} taken off")
        return self.commands.change(act)

    def on_collisions(self, _: s.Empty) -> s.CollisionReport:
        program_id, state = self.commands.read(lambda: (self.meta.program_id, self.twin.state))
        if not program_id:
            raise StateError("no program loaded", state=state, command="collisions")
        report = self.client.check(s.CollisionRequest(program_id=program_id))
        self.commands.read(lambda: self._keep_report(program_id, report))
        return report

    def _keep_report(self, program_id: str, report: s.CollisionReport) -> None:
        """Keep a collision report for the ready checklist, if its program is still the loaded one (on the
        writer; a kept report is no change of the twin: no checkpoint)."""
        if self.meta.program_id == program_id:
            self.collision_report = report

    def on_calibrate(self, _: s.Empty) -> s.CalibrationReport:
        def act() -> tuple[Any, Any, Any]:
            if self.robot is not None:
                raise StateError(f"calibrate refused: it probes the plate with a touch probe, and robot "
                                 f"{self.robot.address} has none configured", state=self.twin.state,
                                 command="calibrate")
            if self.twin.state.in_print:
                raise StateError("cannot calibrate during a print", state=self.twin.state, command="calibrate")
            self.plate.refuse_probing()
            r = self.twin.calibrate()
            self.twin.note("calibrated", {"residual_rms_mm": float(r.residual_rms_mm),
                                          "correction_xyz_mm": [float(v) for v in r.correction_xyz_mm]})
            return (r, *T_to_xyzrpy(self.twin.work_object_T))

        r, wobj_xyz, wobj_rpy = self.commands.change(act)
        return s.CalibrationReport(correction_xyz_mm=list(map(float, r.correction_xyz_mm)),
                                   correction_rpy_deg=list(map(float, r.correction_rpy_deg)),
                                   residual_rms_mm=float(r.residual_rms_mm), points=int(r.n_points),
                                   wobj_xyz_mm=np.asarray(wobj_xyz).tolist(),
                                   wobj_rpy_deg=np.asarray(wobj_rpy).tolist())

    def on_ready(self, _: s.Empty) -> s.ReadyReport:
        return ready_report(self._ready_facts())

    def _ready_facts(self) -> ReadyFacts:
        """What the ready checklist judges: the fabric is asked first (in this thread), then the twin is read
        in one step of the writer."""
        alive = self.client.alive(timeout=2.0)
        program_id, report = self.commands.read(lambda: (self.meta.program_id, self.collision_report))
        collision_error = ""
        if program_id and report is None:
            try:
                report = self.client.check(s.CollisionRequest(program_id=program_id))
                self.commands.read(lambda: self._keep_report(program_id, report))
            except FabricError as err:
                collision_error = err.message

        def read() -> ReadyFacts:
            q = self.twin.pose().q_rad
            program = self.twin.program
            return ReadyFacts(alive=alive, program_id=self.meta.program_id,
                              collisions=report if self.meta.program_id == program_id else None,
                              collision_error=collision_error,
                              pose_known=bool(np.all(np.isfinite(q)) and self.cell.robot.within_limits(q[None, :])[0]),
                              at_home=bool(np.allclose(q, self.cell.home_q_rad, atol=1e-3)),
                              nozzle_c=float(self.twin.temps().nozzle_c),
                              print_temp_c=print_temp_c(program) if program is not None else None,
                              state=self.twin.state, reason=self.twin.reason,
                              plate=self.plate.text() if self.meta.plate_occupied else "",
                              robot=None if self.robot is None else self.robot.status_msg())
        return self.commands.read(read)

    def _time_msg(self) -> s.TimeInfo:
        ti = self.twin.time_info()
        return s.TimeInfo(elapsed_s=float(ti.elapsed_s), total_s=float(ti.total_s), remaining_s=float(ti.remaining_s),
                          estimate_s=float(ti.estimate_s), state=self.twin.state)

    def on_time(self, _: s.Empty) -> s.TimeInfo:
        return self.commands.read(self._time_msg)

    def on_state(self, _: s.Empty) -> s.StationState:
        return self.commands.read(self.msgs.state)

    def on_events(self, req: s.EventsQuery) -> s.EventList:
        last = self.journal.last_seq()
        unknown = sorted(set(req.kinds) - set(EVENT_KINDS))
        if unknown:
            raise ValidationError(f"unknown event kinds {unknown}; kinds: {', '.join(EVENT_KINDS)}", field="kinds")
        evs = self.journal.store.events(since_seq=req.since_seq - 1, limit=req.limit, kinds=list(req.kinds))
        nxt = evs[-1].seq + 1 if evs else max(req.since_seq, last + 1)
        return s.EventList(events=evs, next_seq=nxt, last_seq=last)

    def on_overrides(self, req: s.Overrides) -> s.StationState:
        def act() -> s.StationState:
            self.twin.set_overrides(speed_r=req.speed_r, flow_r=req.flow_r, nozzle_c=req.nozzle_c, bed_c=req.bed_c)
            given = {k: v for k, v in (("speed_r", req.speed_r), ("flow_r", req.flow_r), ("nozzle_c", req.nozzle_c),
                                       ("bed_c", req.bed_c)) if v is not None}
            self.twin.note("override", given)
            return self.msgs.state()
        return self.commands.change(act)

    def on_rtf(self, req: s.StartRequest) -> s.StationState:
        """Change how fast simulated time runs; the simulation itself is unchanged (time is exact)."""
        def act() -> s.StationState:
            self._real_time("rtf", req.rtf)
            self._set_rtf(req.rtf)
            return self.msgs.state()
        return self.commands.change(act)

    def on_mesh(self, req: s.MeshRequest) -> s.Artifact:
        # the beads are copied in one step; the mesh is built in this thread, while the clock goes on
        program, arrays = self.commands.read(lambda: (self.twin.program, self.twin.beads.to_arrays(0)))
        beads = Deposition.from_arrays(program, arrays)
        if len(beads) == 0:
            raise NotFound("nothing has been deposited yet")
        data = beads.export_csv() if req.fmt == "csv" else beads.export_mesh(req.fmt)
        media = {"stl": "model/stl", "glb": "model/gltf-binary", "csv": "text/csv"}[req.fmt]
        return s.Artifact(artifact_id=content_id(data), name=f"as-printed.{req.fmt}", media_type=media, data=data)

    def on_beads(self, req: s.BeadsQuery) -> s.Beads:
        """A page of the beads laid so far (read in one step of the writer), for the collision service's
        checks of live moves. ``part_id`` names this deposit: another print, a cleared plate or a restart
        of the station makes a new one."""
        import uuid
        import weakref

        def read() -> s.Beads:
            beads = self.twin.beads
            ids = self.__dict__.setdefault("_bead_ids", weakref.WeakKeyDictionary())
            part_id = ids.setdefault(beads, uuid.uuid4().hex)
            n = len(beads)
            lo = min(req.first, n)
            hi = min(n, lo + req.limit)
            rows = np.asarray(beads.row[lo:hi], dtype=np.int64)
            program = self.twin.program
            lines = np.full(len(rows), -1, dtype=np.int64)
            if program is not None and len(rows):
                ok = (rows >= 0) & (rows < len(program))
                lines[ok] = program.gcode_line[rows[ok]]
            wobj = program.wobj if program is not None else self.twin.work_object_T
            return s.Beads(part_id=part_id, total=n, first=lo,
                           start_mm=np.array(beads.start_mm[lo:hi], dtype="<f8"),
                           end_mm=np.array(beads.end_mm[lo:hi], dtype="<f8"),
                           width_mm=np.array(beads.width_mm[lo:hi], dtype="<f8"),
                           height_mm=np.array(beads.height_mm[lo:hi], dtype="<f8"),
                           layer=np.array(beads.layer[lo:hi], dtype="<i8"), row=rows.astype("<i8"),
                           gcode_line=lines.astype("<i8"), wobj=np.array(wobj, dtype="<f8"),
                           axis=np.array(beads.axis[lo:hi], dtype="<f8"))
        return self.commands.read(read)


def cell_info_of(cell: Cell) -> s.CellInfo:
    """What the station tells of its cell (``station/cmd/cell``)."""
    robot = cell.to_dict()["robot"]
    return s.CellInfo(name=cell.name, description=cell.description, robot=str(robot.get("name", "")),
                      brand=cell.brand, ik_family=cell.robot.ik_family,
                      joint_names=list(robot["joint_names"]), lower_deg=[float(v) for v in robot["lower_deg"]],
                      upper_deg=[float(v) for v in robot["upper_deg"]], fingerprint=cell.fingerprint())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_cell_argument(parser)
    parser.add_argument("--pose-hz", type=float, default=50.0, help="wall-clock rate of pose telemetry")
    parser.add_argument("--robot", default=None, metavar="KIND:HOST",
                        help="drive this robot controller (franka:HOST); default: the cell file's robot.controller, "
                             "else $FABRIC_ROBOT, else the twin alone ('twin')")
    parser.add_argument("--checkpoint-s", type=float, default=DEFAULT_CHECKPOINT_PERIOD_S,
                        help="wall-clock period of the twin's checkpoints (also taken after every command)")


def build(session: zenoh.Session, cell_id: str, options: argparse.Namespace) -> StationService:
    cell = Cell.load_or_builtin(options.cell_config)
    address = robot_address(getattr(options, "robot", None), cell.controller)
    return StationService(session, cell_id, cell, pose_hz=options.pose_hz,
                          data_dir=service_data_dir(options.data_dir, cell_id, "station"),
                          checkpoint_s=options.checkpoint_s,
                          controller=None if address is None else open_controller(address))
