"""Station service: the digital twin of the cell, run in simulated time, with the paper's commands.

The twin (``fabric.sim.twin.Twin``) is pure simulation; this module gives it a
clock and the fabric. A simulation thread advances the twin by
``dt_wall * rtf`` each tick (``rtf`` 1 = real time; 0 = as fast as possible,
advancing in chunks sized to keep each tick near ``TICK_S`` of wall time).
Simulated time is exact whatever the stepping, because the twin's timeline is
analytic. Every twin event is published on the lossless ``events`` topic and
kept for the ``events`` query; pose, extrusion and temperatures are published
at a fixed wall-clock rate (latest value wins); state on every change.
"""
from __future__ import annotations

import argparse
import collections
import threading
import time
import traceback

import numpy as np
import zenoh

from fabric import schemas as s
from fabric.client import Client
from fabric.errors import CollisionError, FabricError, NotFound, StateError
from fabric.programs import content_id, program_from_artifact
from fabric.readiness import ReadyFacts, print_temp_c, ready_report
from fabric.config import add_cell_argument
from fabric.runtime import Service
from fabric.robot.cell import Cell
from fabric.robot.frames import T_to_xyzrpy
from fabric.sim.twin import Twin

__all__ = ["StationService", "build", "add_arguments"]

TICK_S = 0.02
STATE_PERIOD_S = 0.5          # state also re-published at this period (progress)
EVENT_HISTORY = 200_000


class StationService(Service):
    name = "station"

    def __init__(self, session: zenoh.Session, cell_id: str, cell: Cell, pose_hz: float = 50.0) -> None:
        super().__init__(session, cell_id)
        self.cell, self.twin = cell, Twin(cell)
        self.client = Client(session, cell_id)
        self.pose_period_s = 1.0 / pose_hz
        self.lock = threading.RLock()
        self.rtf = 1.0
        self.program_id = self.job_id = ""
        self.layers_total = 0
        self.collision_report: s.CollisionReport | None = None
        self.history: collections.deque[s.Event] = collections.deque(maxlen=EVENT_HISTORY)
        self._seq_pose = 0
        self._last_state: tuple = ()
        self._last_state_s = 0.0
        self.pub_pose = self.publisher("pose")
        self.pub_extrusion = self.publisher("extrusion")
        self.pub_temps = self.publisher("temps")
        self.pub_state = self.publisher("state", lossless=True)
        self.pub_events = self.publisher("events", lossless=True)
        for command in ("position", "home", "load", "start", "pause", "resume", "stop", "collisions",
                        "calibrate", "ready", "time", "state", "events", "overrides", "rtf", "mesh"):
            self.handle(command, getattr(self, f"on_{command}"))

    def start(self) -> None:
        super().start()
        self._thread = threading.Thread(target=self._sim_loop, name="station:sim", daemon=True)
        self._thread.start()

    def close(self) -> None:
        super().close()
        self._thread.join(timeout=2.0)

    # --- simulation clock ------------------------------------------------------

    def _sim_loop(self) -> None:
        """Run the clock; a failure inside the simulation faults the twin and is logged, never silent."""
        while not self.closed.is_set():
            try:
                self._run_clock()
            except Exception as exc:  # a bug in the simulation: fault the job, keep the station serving
                self.degraded = f"simulation: {type(exc).__name__}: {exc}"
                self.log.error("simulation failed:\n%s", traceback.format_exc())
                with self.lock:
                    self.twin.trip(f"simulation error: {type(exc).__name__}: {exc}")

    def _run_clock(self) -> None:
        last = time.monotonic()
        next_pose = last
        chunk_s = 1.0
        while not self.closed.wait(timeout=max(0.0, min(TICK_S, next_pose - time.monotonic()))):
            now = time.monotonic()
            with self.lock:
                if self.rtf > 0 or self.twin.state != "printing":
                    events = self.twin.advance((now - last) * (self.rtf if self.rtf > 0 else 1.0))
                else:  # as fast as possible: whole chunks until this tick's wall budget is spent
                    events, t0 = [], time.monotonic()
                    while self.twin.state == "printing" and time.monotonic() - t0 < TICK_S:
                        events += self.twin.advance(chunk_s)
                    spent = time.monotonic() - t0
                    chunk_s = float(np.clip(chunk_s * (TICK_S / max(spent, 1e-4)) ** 0.5, 0.05, 600.0))
                last = now
                msgs = [self._event_msg(ev) for ev in events]
                state = self._state_msg()
                pose = self._pose_msg() if now >= next_pose else None
                ext = self._extrusion_msg() if pose else None
                temps = self._temps_msg() if pose else None
            for m in msgs:
                self.pub_events.send(m)
            key = (state.state, state.reason, state.program_id, state.layer, state.rtf, state.speed_r, state.flow_r)
            if key != self._last_state or now - self._last_state_s >= STATE_PERIOD_S:
                self._last_state, self._last_state_s = key, now
                self.pub_state.send(state)
            if pose is not None:
                next_pose = max(next_pose + self.pose_period_s, now)
                self.pub_pose.send(pose)
                self.pub_extrusion.send(ext)
                self.pub_temps.send(temps)

    # --- message builders (called with the lock held) ---------------------------

    def _event_msg(self, ev) -> s.Event:
        msg = s.Event(seq=ev.seq, t_sim_s=ev.t_sim_s, kind=ev.kind, row=ev.row, gcode_line=ev.gcode_line,
                      layer=ev.layer, data=dict(ev.data))
        self.history.append(msg)
        return msg

    def _pose_msg(self) -> s.Pose:
        p = self.twin.pose()
        self._seq_pose += 1
        return s.Pose(seq=self._seq_pose, t_sim_s=self.twin.t_sim_s, q_deg=np.degrees(p.q_rad).tolist(),
                      xyz_mm=list(map(float, p.xyz_mm)), quat_wxyz=list(map(float, p.quat_wxyz)),
                      base_xyz_mm=list(map(float, p.base_xyz_mm)), wall_time_s=time.time())

    def _extrusion_msg(self) -> s.Extrusion:
        e = self.twin.extrusion()
        return s.Extrusion(seq=self._seq_pose, t_sim_s=self.twin.t_sim_s, on=bool(e.on), flow_mm3_s=float(e.flow_mm3_s),
                           extruded_mm3=float(e.extruded_mm3), filament_mm=float(e.filament_mm), layer=int(e.layer),
                           row=int(e.row), gcode_line=int(e.gcode_line), flow_r=float(self.twin.flow_r))

    def _temps_msg(self) -> s.Temps:
        t = self.twin.temps()
        return s.Temps(nozzle_c=float(t.nozzle_c), nozzle_target_c=float(t.nozzle_target_c), bed_c=float(t.bed_c),
                       bed_target_c=float(t.bed_target_c), t_sim_s=self.twin.t_sim_s)

    def _state_msg(self) -> s.StationState:
        ti = self.twin.time_info()
        layer = int(self.twin.extrusion().layer)
        wobj_xyz, wobj_rpy = T_to_xyzrpy(self.twin.work_object_T)
        return s.StationState(state=self.twin.state, reason=self.twin.reason, program_id=self.program_id,
                              job_id=self.job_id, t_sim_s=round(float(ti.elapsed_s), 1), total_s=float(ti.total_s),
                              progress_r=round(float(ti.elapsed_s / ti.total_s), 3) if ti.total_s > 0 else 0.0,
                              layer=layer, layers_total=self.layers_total, rtf=self.rtf,
                              speed_r=float(self.twin.speed_r), flow_r=float(self.twin.flow_r),
                              wobj_xyz_mm=np.asarray(wobj_xyz).tolist(), wobj_rpy_deg=np.asarray(wobj_rpy).tolist())

    def _ack(self, message: str) -> s.Ack:
        return s.Ack(ok=True, message=message, state=self.twin.state)

    # --- the paper's commands ----------------------------------------------------

    def on_position(self, _: s.Empty) -> s.Pose:
        with self.lock:
            return self._pose_msg()

    def on_home(self, _: s.Empty) -> s.Ack:
        with self.lock:
            if self.twin.state in ("printing", "paused"):
                raise StateError(f"cannot go home while {self.twin.state}; stop first",
                                 state=self.twin.state, command="home")
            q_now = self.twin.pose().q_rad
        report = self.client.check(s.CollisionRequest(q_from_deg=np.degrees(q_now).tolist(),
                                                      q_to_deg=np.degrees(self.cell.home_q_rad).tolist()))
        hit = report.first_hit
        if hit is not None:
            raise CollisionError(f"the move home would collide: {hit.body_a} <-> {hit.body_b}", **s.to_plain(hit))
        with self.lock:
            self.twin.go_home()
            return self._ack("moving home (collision-checked)")

    def on_load(self, req: s.LoadRequest) -> s.TimeInfo:
        art = self.client.artifact("planner", req.program_id)
        program = program_from_artifact(art)
        with self.lock:
            if self.twin.state in ("printing", "paused"):
                raise StateError(f"cannot load while {self.twin.state}", state=self.twin.state, command="load")
            self.twin.load(program)
            self.program_id, self.job_id = req.program_id, req.job_id
            self.layers_total = int(program.layer.max() + 1) if len(program) else 0
            self.collision_report = None
            return self._time_msg()

    def on_start(self, req: s.StartRequest) -> s.Ack:
        with self.lock:
            self.rtf = req.rtf
            self.twin.start()
            return self._ack(f"printing at {'max speed' if req.rtf == 0 else f'{req.rtf:g}x real time'}")

    def on_pause(self, _: s.Empty) -> s.Ack:
        with self.lock:
            self.twin.pause()
            return self._ack("paused: extruder off, retracted, lifted clear")

    def on_resume(self, req: s.StartRequest) -> s.Ack:
        with self.lock:
            self.rtf = req.rtf
            self.twin.resume()
            return self._ack("resuming at the paused spot")

    def on_stop(self, _: s.Empty) -> s.Ack:
        with self.lock:
            self.twin.stop()
            return self._ack("stopped: extruder off, moved clear; deposit kept on record")

    def on_collisions(self, _: s.Empty) -> s.CollisionReport:
        if not self.program_id:
            raise StateError("no program loaded", state=self.twin.state, command="collisions")
        report = self.client.check(s.CollisionRequest(program_id=self.program_id))
        self.collision_report = report
        return report

    def on_calibrate(self, _: s.Empty) -> s.CalibrationReport:
        with self.lock:
            if self.twin.state in ("printing", "paused"):
                raise StateError("cannot calibrate during a print", state=self.twin.state, command="calibrate")
            r = self.twin.calibrate()
            wobj_xyz, wobj_rpy = T_to_xyzrpy(self.twin.work_object_T)
        return s.CalibrationReport(correction_xyz_mm=list(map(float, r.correction_xyz_mm)),
                                   correction_rpy_deg=list(map(float, r.correction_rpy_deg)),
                                   residual_rms_mm=float(r.residual_rms_mm), points=int(r.n_points),
                                   wobj_xyz_mm=np.asarray(wobj_xyz).tolist(), wobj_rpy_deg=np.asarray(wobj_rpy).tolist())

    def on_ready(self, _: s.Empty) -> s.ReadyReport:
        return ready_report(self._ready_facts())

    def _ready_facts(self) -> ReadyFacts:
        """What the ready checklist judges: the fabric is asked first (no lock held), then the twin is read."""
        alive = self.client.alive(timeout=2.0)
        collision_error = ""
        if self.program_id and self.collision_report is None:
            try:
                self.collision_report = self.client.check(s.CollisionRequest(program_id=self.program_id))
            except FabricError as err:
                collision_error = err.message
        with self.lock:
            q = self.twin.pose().q_rad
            program = self.twin.program
            return ReadyFacts(alive=alive, program_id=self.program_id, collisions=self.collision_report,
                              collision_error=collision_error,
                              pose_known=bool(np.all(np.isfinite(q)) and self.cell.robot.within_limits(q[None, :])[0]),
                              at_home=bool(np.allclose(q, self.cell.home_q_rad, atol=1e-3)),
                              nozzle_c=float(self.twin.temps().nozzle_c),
                              print_temp_c=print_temp_c(program) if program is not None else None,
                              state=self.twin.state, reason=self.twin.reason)

    def _time_msg(self) -> s.TimeInfo:
        ti = self.twin.time_info()
        return s.TimeInfo(elapsed_s=float(ti.elapsed_s), total_s=float(ti.total_s), remaining_s=float(ti.remaining_s),
                          estimate_s=float(ti.estimate_s), state=self.twin.state)

    def on_time(self, _: s.Empty) -> s.TimeInfo:
        with self.lock:
            return self._time_msg()

    def on_state(self, _: s.Empty) -> s.StationState:
        with self.lock:
            return self._state_msg()

    def on_events(self, req: s.EventsQuery) -> s.EventList:
        with self.lock:
            evs = [e for e in self.history if e.seq >= req.since_seq][: req.limit]
            nxt = (self.history[-1].seq + 1) if self.history else 0
        return s.EventList(events=evs, next_seq=nxt)

    def on_overrides(self, req: s.Overrides) -> s.StationState:
        with self.lock:
            self.twin.set_overrides(speed_r=req.speed_r, flow_r=req.flow_r, nozzle_c=req.nozzle_c, bed_c=req.bed_c)
            return self._state_msg()

    def on_rtf(self, req: s.StartRequest) -> s.StationState:
        """Change how fast simulated time runs; the simulation itself is unchanged (time is exact)."""
        with self.lock:
            self.rtf = req.rtf
            return self._state_msg()

    def on_mesh(self, req: s.MeshRequest) -> s.Artifact:
        with self.lock:
            if len(self.twin.beads) == 0:
                raise NotFound("nothing has been deposited yet")
            data = self.twin.beads.export_mesh(req.fmt)
        media = "model/stl" if req.fmt == "stl" else "model/gltf-binary"
        return s.Artifact(artifact_id=content_id(data), name=f"as-printed.{req.fmt}", media_type=media, data=data)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_cell_argument(parser)
    parser.add_argument("--pose-hz", type=float, default=50.0, help="wall-clock rate of pose telemetry")


def build(session: zenoh.Session, cell_id: str, options: argparse.Namespace) -> StationService:
    cell = Cell.load_or_builtin(options.cell_config)
    return StationService(session, cell_id, cell, pose_hz=options.pose_hz)
