"""The digital twin: runs a loaded program in simulated time with the print state machine.

States: ``idle`` (nothing loaded, or a job just finished), ``ready`` (a
validated program is loaded), ``printing``, ``paused``, ``stopped``, ``fault``.
Commands change the state at once; the motion they cause then runs in
simulated time, and :meth:`Twin.advance` reports what physically happened as
:class:`Event` s, in order, with their exact times (never rounded to a step).

Motion is a queue of *legs*, each a :class:`~fabric.sim.timeline.Timeline`
with an absolute start: the program (re-timed from a row when an override
changes it), a controlled stop, the pause/stop moves (retract, lift straight
up along the plate normal), the resume moves (straight down at
``resume_speed_mm_s`` to the exact stop point, unretract) and homing. A leg
may be *cut* (a pause, an override, a fault): it then ends at a given time and
owns only the rows up to there. Legs that continue the program are timed when
they start, so the heaters and overrides they see are the ones of that moment.

Pause is a controlled stop: the TCP keeps following the path and slows at the
acceleration limit (extruding with flow tied to the speed, as a synchronised
extruder does), so the stop point lies a little beyond where the command came;
during a joint move or a retraction the row is finished first; a dwell or a
heat-up is interrupted and redone on resume. Then extruder off, retract, lift.
Resume goes back down to the recorded point, unretracts and continues the row
from rest. Because a bead is recorded when its row completes, from the row's
own start and end points, and volumes are the flow per mm times the distance
actually covered, a paused print gives the same beads as an uninterrupted one.
Stop is the same controlled stop, then retract and lift, heaters off, and the
row in progress is recorded as a partial bead.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from fabric.errors import CollisionError, FabricError, StateError, UnreachableError, ValidationError
from fabric.sim.calibration import CalibrationResult, calibrate_plate
from fabric.sim.deposition import Deposition
from fabric.sim.frames import R_from_quat, inv_T, make_T, quat_from_R, rot_x
from fabric.sim.kinematics import IK_OK, IK_SINGULAR
from fabric.sim.motion import (DEFAULT_RETRACT_SPEED_MM_S, StartState, mini_program, stop_timeline, time_program,
                               validate_program)
from fabric.sim.program import MOVEJ, MOVEL, RETRACT, SET_TEMP, WAIT, WAIT_TEMP, Program
from fabric.sim.thermal import HEATER_NAMES, Thermal
from fabric.sim.timeline import Leg, Sample, Timeline

__all__ = ["Twin", "Event", "Pose", "ExtrusionState", "Temps", "TimeInfo", "STATES", "EVENT_KINDS"]

STATES = ("idle", "ready", "printing", "paused", "stopped", "fault")
EVENT_KINDS = ("layer", "extruder_on", "extruder_off", "paused", "resumed", "stopped", "finished",
               "fault", "temp_reached", "home")
_IK_ACCEPT = (IK_OK, IK_SINGULAR)   # a solution is returned


@dataclass
class Event:
    """Something that happened at simulated time ``t_sim_s`` (``seq`` counts from 1 per twin)."""

    seq: int
    t_sim_s: float
    kind: str
    row: int
    gcode_line: int
    layer: int
    data: dict[str, Any] = field(default_factory=dict)


@dataclass
class Pose:
    """Joints, TCP in the plate frame (the twin's current work object) and TCP in the base frame."""

    q_rad: np.ndarray
    xyz_mm: np.ndarray
    quat_wxyz: np.ndarray
    base_xyz_mm: np.ndarray


@dataclass
class ExtrusionState:
    """Extruder now: on/off, flow, totals since start, and where in the program the twin is."""

    on: bool
    flow_mm3_s: float
    extruded_mm3: float
    filament_mm: float
    layer: int
    row: int
    gcode_line: int


@dataclass
class Temps:
    """Heater temperatures now and their set points (C)."""

    nozzle_c: float
    nozzle_target_c: float
    bed_c: float
    bed_target_c: float


@dataclass
class TimeInfo:
    """Simulated time of the job: elapsed since start, expected total and remaining, and the
    estimate made before it started (equal to the executed total when nothing interferes)."""

    elapsed_s: float
    total_s: float
    remaining_s: float
    estimate_s: float


class Twin:
    """A simulated cell running one job at a time (see module docstring)."""

    def __init__(self, cell: Any, *, accel_mm_s2: float = 2000.0, retract_mm: float = 1.0, lift_mm: float = 5.0,
                 resume_speed_mm_s: float = 50.0, probe_noise_mm: float = 0.01, rng_seed: int = 0,
                 retract_speed_mm_s: float = DEFAULT_RETRACT_SPEED_MM_S, home_vel_r: float = 0.5,
                 filament_diameter_mm: float = 1.75, thermal: Thermal | None = None) -> None:
        for name, val in (("accel_mm_s2", accel_mm_s2), ("resume_speed_mm_s", resume_speed_mm_s),
                          ("retract_speed_mm_s", retract_speed_mm_s), ("home_vel_r", home_vel_r),
                          ("filament_diameter_mm", filament_diameter_mm)):
            if not math.isfinite(val) or val <= 0:
                raise ValidationError(f"{name} must be > 0, got {val}", field=name)
        for name, val in (("retract_mm", retract_mm), ("lift_mm", lift_mm), ("probe_noise_mm", probe_noise_mm)):
            if not math.isfinite(val) or val < 0:
                raise ValidationError(f"{name} must be >= 0, got {val}", field=name)
        # configuration
        self.cell = cell
        self.robot = cell.robot
        self.accel_mm_s2, self.retract_mm, self.lift_mm = float(accel_mm_s2), float(retract_mm), float(lift_mm)
        self.resume_speed_mm_s, self.retract_speed_mm_s = float(resume_speed_mm_s), float(retract_speed_mm_s)
        self.home_vel_r = min(float(home_vel_r), 1.0)
        self.probe_noise_mm = float(probe_noise_mm)
        self._filament_area_mm2 = math.pi * filament_diameter_mm ** 2 / 4.0
        self._rng = np.random.default_rng(rng_seed)
        self._work_T = np.asarray(cell.wobj_T(), dtype=float).copy()
        # state
        self.state, self.reason, self.t_sim_s = "idle", "", 0.0
        self._thermal = thermal.copy() if thermal is not None else Thermal()
        self._program: Program | None = None
        self._beads = Deposition()
        self._legs: list[Leg] = []
        self._pending: list[Event] = []
        self._seq = 0
        self._sample: Sample | None = None
        self._sample_key: tuple[float, int, float] | None = None
        self._speed_r, self._flow_r = 1.0, 1.0
        self._estimate_s = 0.0
        self._t_started: float | None = None
        self._t_ended: float | None = None
        q_home = np.asarray(cell.home_q_rad, dtype=float)
        self._rest_q = q_home.copy()
        self._rest_T = np.asarray(self.robot.fk(q_home[None]))[0]
        self._reset_job()

    def _reset_job(self) -> None:
        self._extruded_done = 0.0
        self._retract_total_mm = 0.0
        self._retracted = False
        self._carry: dict[int, float] = {}
        self._ext_on = False
        self._layer, self._row = -1, 0
        self._resume_at: tuple[int, float, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._pause_retract_mm = 0.0
        self._pause_preview_s: float | None = None

    # ------------------------------------------------------------------ queries

    @property
    def beads(self) -> Deposition:
        """Beads deposited by the current (or last) job."""
        return self._beads

    @property
    def work_object_T(self) -> np.ndarray:
        """The plate frame in the base frame as the twin believes it (updated by :meth:`calibrate`)."""
        return self._work_T.copy()

    @property
    def program(self) -> Program | None:
        """The loaded program (None when nothing is loaded)."""
        return self._program

    @property
    def moving(self) -> bool:
        """True while any motion (program, pause/stop moves, homing) is still to run."""
        return bool(self._legs)

    def _now_sample(self) -> tuple[Sample | None, Leg | None]:
        """The running leg's sample now (cached per simulated instant: telemetry reads it often)."""
        leg = self._legs[0] if self._legs and self._legs[0].placed else None
        if leg is None:
            return None, None
        key = (self.t_sim_s, id(leg), leg.t_cut)
        if self._sample_key != key:
            self._sample = leg.tl.sample(min(max(self.t_sim_s - leg.t0, 0.0), leg.t_cut))
            self._sample_key = key
        return self._sample, leg

    def pose(self) -> Pose:
        """Where the robot is now (commanded pose of the twin)."""
        smp, leg = self._now_sample()
        if smp is not None and np.array_equal(leg.tl.program.wobj, self._work_T):
            return Pose(np.array(smp.q_rad, dtype=float), np.array(smp.xyz_mm, dtype=float),
                        np.array(smp.quat_wxyz, dtype=float), np.array(smp.base_xyz_mm, dtype=float))
        if smp is None:
            q, T = self._rest_q, self._rest_T
        else:
            q = smp.q_rad
            T = leg.tl.program.wobj @ make_T(R_from_quat(smp.quat_wxyz), smp.xyz_mm)
        Tp = inv_T(self._work_T) @ T
        return Pose(np.array(q, dtype=float), Tp[:3, 3].copy(), quat_from_R(Tp[:3, :3]), T[:3, 3].copy())

    def extrusion(self) -> ExtrusionState:
        """Extruder on/off and flow now; volume and filament pushed since start (retractions included)."""
        smp, leg = self._now_sample()
        flow, extra = 0.0, 0.0
        if smp is not None and leg.main and smp.extruding:
            flow = smp.flow_mm3_s
            j = smp.row - leg.tl.start_row
            if j >= leg.done:   # the row in progress: the part covered so far
                s0 = leg.tl.s0_mm if j == 0 else 0.0
                extra = float(leg.tl.program.flow_mm3_mm[smp.row]) * leg.tl.flow_r * (smp.s_mm - s0)
        vol = self._extruded_done + extra
        g = int(self._program.gcode_line[self._row]) if self._program is not None else -1
        return ExtrusionState(self._ext_on, float(flow), vol, vol / self._filament_area_mm2 + self._retract_total_mm,
                              self._layer, self._row, g)

    def temps(self) -> Temps:
        """Nozzle and bed temperatures now (closed form: exact at any step)."""
        th, t = self._thermal, self.t_sim_s
        return Temps(th.temp_at(0, t), th.target(0), th.temp_at(1, t), th.target(1))

    def time_info(self) -> TimeInfo:
        """Elapsed, expected total and remaining simulated time of the job (paused: if resumed now)."""
        if self.state == "ready":
            return TimeInfo(0.0, self._estimate_s, self._estimate_s, self._estimate_s)
        if self._t_started is None:
            return TimeInfo(0.0, 0.0, 0.0, self._estimate_s)
        end = self._t_ended if self._t_ended is not None else self.t_sim_s
        elapsed = end - self._t_started
        remaining = 0.0
        if self.state == "printing":
            remaining = self._legs_remaining_s()
        elif self.state == "paused":
            remaining = self._legs_remaining_s() + self._resume_preview_s()
        return TimeInfo(elapsed, elapsed + remaining, remaining, self._estimate_s)

    # ------------------------------------------------------------------ commands

    def _refuse(self, command: str, allowed: tuple[str, ...]) -> None:
        if self.state not in allowed:
            raise StateError(f"cannot {command} while {self.state}", state=self.state, command=command,
                             allowed=list(allowed))

    def _busy(self, command: str) -> None:
        if self._legs:
            raise StateError(f"cannot {command} while the robot is moving", state=self.state, command=command,
                             reason="moving")

    def load(self, program: Program) -> TimeInfo:
        """Validate ``program`` and make it the job (state ``ready``); returns the time estimate."""
        self._refuse("load", ("idle", "ready", "stopped", "fault"))
        validate_program(program, self.robot)
        dp = np.abs(program.wobj - self._work_T)
        if dp[:3, 3].max() > 0.01 or dp[:3, :3].max() > 1e-6:
            raise ValidationError("the program was planned for another work object than the twin's: re-plan it "
                                  "for the current (calibrated) work object", field="wobj",
                                  program_wobj=program.wobj, twin_wobj=self._work_T)
        tl = self._main_builder(program, 0, None, 0.0, 0.0)(self.t_sim_s)
        self._program, self._estimate_s = program, tl.total_s
        self._beads = Deposition(program)
        self._reset_job()
        self._t_started = self._t_ended = None
        self.state, self.reason = "ready", f"loaded {len(program)} rows"
        return TimeInfo(0.0, self._estimate_s, self._estimate_s, self._estimate_s)

    def start(self) -> None:
        """Run the loaded program from its start."""
        self._refuse("start", ("ready",))
        self._busy("start")
        assert self._program is not None
        self._reset_job()
        self._beads = Deposition(self._program)
        leg = Leg(None, True, ["finished"], build=self._main_builder(self._program, 0, None, 0.0, 0.0))
        self._enqueue(leg)
        self._estimate_s = leg.tl.total_s
        self._t_started, self._t_ended = self.t_sim_s, None
        self.state, self.reason = "printing", "started"

    def pause(self) -> None:
        """Controlled stop, extruder off, retract, lift; ``paused`` event once the robot is clear."""
        self._refuse("pause", ("printing",))
        self.state, self.reason = "paused", "paused by operator"
        self._command(lambda: self._halt("paused"))

    def resume(self) -> None:
        """Back down to the stop point, unretract, continue the program from there."""
        self._refuse("resume", ("paused",))
        self.state, self.reason = "printing", "resumed"
        self._command(self._resume_legs)

    def stop(self) -> None:
        """Abort: controlled stop, retract, lift, heaters off; the beads printed stay on record."""
        self._refuse("stop", ("printing", "paused"))
        was = self.state
        self.state, self.reason = "stopped", "stopped by operator"
        for h in (0, 1):
            self._thermal.set_target(h, 0.0, self.t_sim_s)
        if was == "printing":
            self._command(lambda: self._halt("stopped"))
        elif self._legs:
            self._legs[-1].end_kinds = ["stopped" if k == "paused" else k for k in self._legs[-1].end_kinds]
        else:
            self._on_end("stopped", self.t_sim_s, self._pending)

    def go_home(self, collision_ok: bool = True) -> None:
        """Joint move to the cell's home joints (``collision_ok``: the collision service's verdict)."""
        self._refuse("go_home", ("idle", "ready", "stopped", "fault"))
        if not collision_ok:
            raise CollisionError("the home move was refused by the collision check", command="go_home")
        q, xyz, quat, wobj = self._queue_end_pose()
        home = np.asarray(self.cell.home_q_rad, dtype=float)
        Th = inv_T(wobj) @ np.asarray(self.robot.fk(home[None]))[0]
        prog = mini_program([{"op": MOVEJ, "q_rad": home, "xyz_mm": Th[:3, 3], "quat_wxyz": quat_from_R(Th[:3, :3]),
                              "vel_r": self.home_vel_r}], wobj)
        tl = time_program(prog, self.robot, start_state=StartState(q, xyz, quat))
        self._enqueue(Leg(tl, False, ["home"]))
        self.reason = "homing"

    def trip(self, reason: str) -> None:
        """Put the twin in ``fault`` now (e.g. a monitor saw something wrong): instant stop."""
        self._fault(reason, self._pending)

    def set_overrides(self, speed_r: float | None = None, flow_r: float | None = None,
                      nozzle_c: float | None = None, bed_c: float | None = None) -> None:
        """Live overrides. Speed and flow take effect from the next row (the rest is re-timed);
        set points at once (a heat-up in progress is re-timed)."""
        for name, val in (("speed_r", speed_r), ("flow_r", flow_r)):
            if val is not None and (not math.isfinite(val) or not 0.0 < val <= 10.0):
                raise ValidationError(f"{name} must be in (0, 10], got {val}", field=name)
        temp = False
        for h, val in ((0, nozzle_c), (1, bed_c)):
            if val is not None:
                self._thermal.set_target(h, float(val), self.t_sim_s)
                temp = True
        if speed_r is not None:
            self._speed_r = float(speed_r)
        if flow_r is not None:
            self._flow_r = float(flow_r)
        self._pause_preview_s = None
        for leg in self._legs:
            leg.preview_s = None
        if self.state == "printing" and self._legs and self._legs[0].main:
            self._command(lambda: self._retime(temp))

    def calibrate(self) -> CalibrationResult:
        """Probe the plate, fit its true frame and make it the work object (see calibration module).

        A program loaded before is unloaded (state ``idle``): it must be re-planned for the new frame."""
        self._refuse("calibrate", ("idle", "ready", "stopped", "fault"))
        self._busy("calibrate")
        lo, hi = self._plate_box()
        res, _plan, frames = calibrate_plate(self._work_T, np.asarray(self.cell.true_wobj_T(), float), lo, hi,
                                            self.probe_noise_mm, self._rng)
        T = make_T(frames[:, :3, :3] @ rot_x(np.pi), res.points_base_mm)
        _q, status = self.robot.ik(T, self._rest_q)
        bad = ~np.isin(np.asarray(status), _IK_ACCEPT)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise UnreachableError(f"probe {i} at {np.round(res.points_base_mm[i], 2).tolist()} mm is unreachable",
                                   probe=i, reason=int(np.asarray(status)[i]), gcode_line=-1)
        self._work_T = res.work_object_T.copy()
        if self.state == "ready":
            self._program = None
            self.state, self.reason = "idle", "calibrated: re-plan the program for the new work object"
        return res

    # ------------------------------------------------------------------ simulation

    def advance(self, dt_sim_s: float) -> list[Event]:
        """Move simulated time forward by exactly ``dt_sim_s``; every event that happened, in order."""
        if not math.isfinite(dt_sim_s) or dt_sim_s < 0:
            raise ValidationError(f"dt_sim_s must be finite and >= 0, got {dt_sim_s}", field="dt_sim_s")
        t_target = self.t_sim_s + dt_sim_s
        events, self._pending = self._pending, []
        t_here = self.t_sim_s
        try:
            while self._legs:
                leg = self._legs[0]
                end = leg.t0 + leg.t_cut
                final = t_target >= end
                t_here = end if final else t_target
                self._run_leg(leg, leg.t_cut if final else t_target - leg.t0, final, events)
                if not final:
                    break
                self._finish_leg(leg, events)
        except FabricError as err:
            self._fault(f"{err.code}: {err.message}", events, t_here)
        self.t_sim_s = t_target
        self._sample_key = None
        return events

    def _run_leg(self, leg: Leg, tau: float, final: bool, events: list[Event]) -> None:
        """Process the rows of ``leg`` that start or complete by local time ``tau``."""
        ns, nd = leg.cursor(tau, final)
        if ns == leg.started and nd == leg.done:
            return
        it = leg.interesting
        for j in it[np.searchsorted(it, leg.done):np.searchsorted(it, ns)].tolist():
            if j >= leg.started:
                self._row_start(leg, j, events)
            if j < nd:
                self._row_done(leg, j, events)
        if leg.main:
            if nd > leg.done:
                self._deposit(leg, leg.done, nd)
                self._extruded_done += float(leg.cumvol_mm3[nd] - leg.cumvol_mm3[leg.done])
            if ns > 0:
                self._row = leg.tl.start_row + ns - 1
        leg.started, leg.done = ns, nd

    def _row_start(self, leg: Leg, j: int, events: list[Event]) -> None:
        tl = leg.tl
        p, r, t = tl.program, tl.start_row + j, leg.t0 + float(tl.t_start_s[j])
        if leg.main:
            self._row = r
        if leg.main and p.layer[r] >= 0 and p.layer[r] != self._layer:
            self._layer = int(p.layer[r])
            self._emit(events, t, "layer", {"z_mm": float(p.xyz_mm[r, 2])})
        if leg.ext[j] >= 0 and bool(leg.ext[j]) != self._ext_on:
            self._ext_on = bool(leg.ext[j])
            self._emit(events, t, "extruder_on" if self._ext_on else "extruder_off",
                       {"flow_mm3_mm": float(p.flow_mm3_mm[r]) * tl.flow_r} if self._ext_on else {})
        if p.op[r] == SET_TEMP:
            self._thermal.set_target(int(p.aux[r]), float(p.value[r]), t)

    def _row_done(self, leg: Leg, j: int, events: list[Event]) -> None:
        tl = leg.tl
        p, r, t = tl.program, tl.start_row + j, leg.t0 + float(tl.t_end_s[j])
        if p.op[r] == WAIT_TEMP:
            h = int(p.aux[r])
            self._emit(events, t, "temp_reached", {"heater": HEATER_NAMES[h], "temp_c": self._thermal.temp_at(h, t),
                                                   "target_c": self._thermal.target(h)})
        elif p.op[r] == RETRACT:
            self._retract_total_mm += float(p.value[r])
            self._retracted = bool(p.value[r] < 0)

    def _deposit(self, leg: Leg, a: int, b: int) -> None:
        """Record the beads of main-program rows ``a .. b-1`` of ``leg`` (just completed), vectorised."""
        tl = leg.tl
        p = tl.program
        j = np.arange(a, b)
        r = tl.start_row + j
        keep = (p.op[r] == MOVEL) & (p.flow_mm3_mm[r] > 0)
        j, r = j[keep], r[keep]
        if len(j) == 0:
            return
        keep = tl.row_length_mm(j) > 0
        j, r = j[keep], r[keep]
        if len(j) == 0:
            return
        vol = leg.vol_mm3[j].copy()
        if j[0] == 0:
            vol[0] += self._carry.pop(int(r[0]), 0.0)
        _, start, _ = tl.from_pose(j)
        self._beads.add(r, p.layer[r], start, p.xyz_mm[r], vol, p.flow_mm3_mm[r])

    def _finish_leg(self, leg: Leg, events: list[Event]) -> None:
        """The leg ended: keep the unfinished row's volume, record the pose, fire its end events."""
        tl = leg.tl
        p = tl.program
        if leg.partial_end and leg.main:
            j = leg.n_rows - 1
            r = tl.start_row + j
            if p.op[r] == MOVEL:
                s, _ = tl.profile(np.array([j]), np.array([leg.t_cut - tl.t_start_s[j]]))
                piece = float(p.flow_mm3_mm[r]) * tl.flow_r * float(s[0])
                self._carry[r] = self._carry.get(r, 0.0) + piece
                self._extruded_done += piece
        smp = tl.sample(leg.t_cut)
        self._rest_q = np.array(smp.q_rad, dtype=float)
        self._rest_T = p.wobj @ make_T(R_from_quat(smp.quat_wxyz), smp.xyz_mm)
        self._legs.pop(0)
        t_end = leg.t0 + leg.t_cut
        for kind in leg.end_kinds:
            self._on_end(kind, t_end, events)
        if self._legs:
            self._legs[0].place(t_end)

    def _on_end(self, kind: str, t: float, events: list[Event]) -> None:
        if kind == "finished":
            self.state, self.reason = "idle", "finished"
            self._t_ended = t
            self._emit(events, t, kind, {"elapsed_s": t - (self._t_started or 0.0),
                                         "extruded_mm3": self._extruded_done, "beads": len(self._beads)})
        elif kind == "stopped":
            self._record_partial()
            self._t_ended = t
            self._emit(events, t, kind, {"extruded_mm3": self._extruded_done, "beads": len(self._beads)})
        elif kind == "resumed":
            self._resume_at = None
            self._emit(events, t, kind)
        elif kind == "paused" and self._resume_at is not None:
            row, s, _q, xyz, _quat = self._resume_at
            self._emit(events, t, kind, {"resume_row": row, "resume_s_mm": s, "xyz_mm": xyz.tolist()})
        else:
            self._emit(events, t, kind)

    def _emit(self, events: list[Event], t: float, kind: str, data: dict[str, Any] | None = None) -> None:
        p = self._program
        g = int(p.gcode_line[min(self._row, len(p) - 1)]) if p is not None else -1
        self._seq += 1
        events.append(Event(self._seq, float(t), kind, self._row, g, self._layer, data or {}))

    def _record_partial(self) -> None:
        """The row in progress when a job ends early: a partial bead from its start to the stop point."""
        p = self._program
        if p is None or not self._carry:
            self._carry.clear()
            return
        for r, vol in sorted(self._carry.items()):
            if self._resume_at is not None and self._resume_at[0] == r:
                end = self._resume_at[3]
            else:
                end = (inv_T(p.wobj) @ self._rest_T)[:3, 3]
            start = p.xyz_mm[r - 1] if r > 0 else end
            if vol > 0:
                self._beads.add(np.array([r]), p.layer[r:r + 1], start[None], np.asarray(end)[None], np.array([vol]),
                                p.flow_mm3_mm[r:r + 1])
        self._carry.clear()
        self._resume_at = None

    def _fault(self, reason: str, events: list[Event], t: float | None = None) -> None:
        """Instant stop at ``t`` (default now), extruder and heaters off, state ``fault``."""
        self._sample_key = None
        t = self.t_sim_s if t is None else t
        if self._legs and self._legs[0].placed:
            leg = self._legs[0]
            tau = min(max(t - leg.t0, 0.0), leg.t_cut)
            try:
                self._run_leg(leg, tau, False, events)
                leg.cut_at(tau)
                leg.end_kinds = []
                self._legs = [leg]
                self._finish_leg(leg, events)
            except FabricError as err:          # the twin stops anyway; say why the pose may be stale
                reason = f"{reason} (stopping at the fault point failed: {err.message})"
        self._legs = []
        if self._ext_on:
            self._ext_on = False
            self._emit(events, t, "extruder_off")
        for h in (0, 1):
            self._thermal.set_target(h, 0.0, t)
        self._record_partial()
        if self._t_started is not None and self._t_ended is None:
            self._t_ended = t
        self.state, self.reason = "fault", reason
        self._emit(events, t, "fault", {"reason": reason})

    # ------------------------------------------------------------------ legs

    def _command(self, fn: Callable[[], None]) -> None:
        """Run a command's motion planning; a failure there (e.g. an unreachable lift) is a fault."""
        try:
            fn()
        except FabricError as err:
            self._fault(f"{err.code}: {err.message}", self._pending)
        self._sample_key = None

    def _enqueue(self, leg: Leg) -> None:
        self._sample_key = None
        self._legs.append(leg)
        if len(self._legs) == 1:
            leg.place(self.t_sim_s)

    def _main_builder(self, program: Program, row: int, pose: tuple[np.ndarray, ...] | None, s_mm: float,
                      v_mm_s: float) -> Callable[[float], Timeline]:
        """Times the program from ``row`` when called with the leg's start time (overrides, heaters then)."""
        def build(t0: float) -> Timeline:
            if pose is None:
                ss = StartState.at_joints(self.robot, program.wobj, self._rest_q, self._thermal.copy(), t0)
            else:
                ss = StartState(pose[0], pose[1], pose[2], s_mm, v_mm_s, self._thermal.copy(), t0)
            return time_program(program, self.robot, self._speed_r, row, ss, accel_mm_s2=self.accel_mm_s2,
                                flow_r=self._flow_r, retract_speed_mm_s=self.retract_speed_mm_s)
        return build

    def _leg_end_pose(self, leg: Leg) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        tl = leg.tl
        smp = tl.sample(leg.t_cut if leg.n_rows else tl.total_s)
        return smp.q_rad, smp.xyz_mm, smp.quat_wxyz, tl.program.wobj

    def _queue_end_pose(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Joints, TCP (plate frame) and that plate frame where the queued motion ends."""
        if self._legs and self._legs[-1].tl is not None:
            return self._leg_end_pose(self._legs[-1])
        wobj = self._program.wobj if self._program is not None else self._work_T
        if self._legs:                              # a lazy program leg: it ends on the last row
            p = self._program
            return p.q_rad[-1], p.xyz_mm[-1], p.quat_wxyz[-1], wobj
        Tp = inv_T(wobj) @ self._rest_T
        return self._rest_q.copy(), Tp[:3, 3].copy(), quat_from_R(Tp[:3, :3]), wobj

    def _retracted_after_queue(self) -> bool:
        r = self._retracted
        for leg in self._legs:
            if leg.tl is None:
                continue
            p, rows = leg.tl.program, leg.tl.rows[leg.done:(leg.n_rows or leg.tl.n)]
            rr = rows[p.op[rows] == RETRACT]
            if len(rr):
                r = bool(p.value[rr[-1]] < 0)
        return r

    def _ik_one(self, wobj: np.ndarray, xyz: np.ndarray, quat: np.ndarray, seed: np.ndarray) -> np.ndarray:
        T = wobj @ make_T(R_from_quat(quat), xyz)
        q, status = self.robot.ik(T[None], np.asarray(seed, dtype=float))
        if int(np.asarray(status).reshape(-1)[0]) not in _IK_ACCEPT:
            raise UnreachableError(f"pose {np.round(xyz, 3).tolist()} mm (plate frame) is unreachable",
                                   reason=int(np.asarray(status).reshape(-1)[0]), gcode_line=-1)
        return np.asarray(q, dtype=float).reshape(-1, len(seed))[0]

    def _time_aux(self, rows: list[dict[str, Any]], pose: tuple[np.ndarray, ...], end_kinds: list[str]) -> Leg:
        q, xyz, quat, wobj = pose
        tl = time_program(mini_program(rows, wobj), self.robot, start_state=StartState(q, xyz, quat),
                          accel_mm_s2=self.accel_mm_s2, retract_speed_mm_s=self.retract_speed_mm_s)
        return Leg(tl, False, end_kinds)

    def _lift_leg(self, pose: tuple[np.ndarray, ...], end_kind: str) -> Leg:
        """Retract (unless already retracted) and move straight up ``lift_mm`` along the plate normal."""
        q, xyz, quat, wobj = pose
        here = {"q_rad": q, "xyz_mm": xyz, "quat_wxyz": quat}
        rows: list[dict[str, Any]] = []
        self._pause_retract_mm = 0.0
        if self.retract_mm > 0 and not self._retracted_after_queue():
            rows.append({"op": RETRACT, "value": -self.retract_mm, **here})
            self._pause_retract_mm = self.retract_mm
        if self.lift_mm > 0:
            up = np.asarray(xyz, dtype=float) + [0.0, 0.0, self.lift_mm]
            rows.append({"op": MOVEL, "q_rad": self._ik_one(wobj, up, quat, q), "xyz_mm": up, "quat_wxyz": quat,
                         "speed_mm_s": self.resume_speed_mm_s})
        if not rows:
            rows.append({"op": WAIT, "value": 0.0, **here})
        return self._time_aux(rows, pose, [end_kind])

    def _halt(self, end_kind: str) -> None:
        """Controlled stop of the running motion, then retract and lift (pause and stop)."""
        head = self._legs[0]
        tau = min(max(self.t_sim_s - head.t0, 0.0), head.t_cut)
        queue: list[Leg] = []
        if head.main:
            tl = head.tl
            j = head.row_at(tau)
            r = tl.start_row + j
            op = tl.program.op[r]
            if op == MOVEL and tl.len_mm[j] > 0:
                head.cut_at(tau)
                st, row, s = stop_timeline(tl, tau)
                if st is not None:
                    dl = Leg(st, True, [])
                    dl.partial_end = row == st.start_row + st.n - 1
                    queue.append(dl)
            elif op in (WAIT, WAIT_TEMP):
                head.cut_at(tau)
                row, s = r, 0.0
            else:
                head.cut_after(j)
                row, s = r + 1, 0.0
            head.end_kinds = []
            pose = self._leg_end_pose(queue[-1] if queue else head)
            self._resume_at = (row, s, pose[0], pose[1], pose[2])
        elif {"paused", "stopped"} & set(head.end_kinds):
            # still lifting from the previous pause: cancel the queued resume, keep lifting
            self._legs = [head]
            head.end_kinds = [end_kind]
            self._pause_preview_s = None
            return
        else:
            # going back down to resume: that resume never completes; lift again from where it ends
            head.end_kinds = []
            pose = self._leg_end_pose(head)
        self._legs = [head] + queue
        self._legs.append(self._lift_leg(pose, end_kind))
        self._pause_preview_s = None

    def _make_resume_legs(self) -> list[Leg]:
        assert self._resume_at is not None and self._program is not None
        row, s, q, xyz, quat = self._resume_at
        start = self._queue_end_pose()
        back = {"q_rad": q, "xyz_mm": xyz, "quat_wxyz": quat}
        rows: list[dict[str, Any]] = [{"op": MOVEL, **back, "speed_mm_s": self.resume_speed_mm_s}]
        if self._pause_retract_mm > 0:
            rows.append({"op": RETRACT, "value": self._pause_retract_mm, **back})
        aux = self._time_aux(rows, start, ["resumed"])
        if row >= len(self._program):
            aux.end_kinds.append("finished")
            return [aux]
        main = Leg(None, True, ["finished"], build=self._main_builder(self._program, row, (q, xyz, quat), s, 0.0))
        return [aux, main]

    def _resume_legs(self) -> None:
        for leg in self._make_resume_legs():
            self._enqueue(leg)
        self._pause_retract_mm = 0.0
        self._pause_preview_s = None

    def _retime(self, temp_changed: bool) -> None:
        """Re-time the program after the running row (or redo a heat-up whose set point changed)."""
        head = self._legs[0]
        tl = head.tl
        p = tl.program
        tau = min(max(self.t_sim_s - head.t0, 0.0), head.t_cut)
        j = head.row_at(tau)
        r = tl.start_row + j
        if p.op[r] == WAIT_TEMP and temp_changed:
            head.cut_at(tau)
            nxt, pose, v = r, (p.q_rad[r], p.xyz_mm[r], p.quat_wxyz[r]), 0.0
        elif j >= tl.n - 1:
            return
        else:
            head.cut_after(j)
            nxt, pose = r + 1, (p.q_rad[r], p.xyz_mm[r], p.quat_wxyz[r])
            v = float(tl.v1_mm_s[j]) if p.op[r] == MOVEL else 0.0
        head.end_kinds = []
        self._legs = [head, Leg(None, True, ["finished"], build=self._main_builder(p, nxt, pose, 0.0, v))]

    def _legs_remaining_s(self) -> float:
        total, t = 0.0, self.t_sim_s
        for k, leg in enumerate(self._legs):
            if k == 0 and leg.placed:
                rem = leg.t0 + leg.t_cut - t
            elif leg.tl is not None:
                rem = leg.t_cut if leg.n_rows else leg.tl.total_s
            else:
                if leg.preview_s is None:
                    leg.preview_s = leg.build(t + total).total_s
                rem = leg.preview_s
            total += max(rem, 0.0)
        return total

    def _resume_preview_s(self) -> float:
        """Time a resume would take from now (the resume moves plus the rest of the program)."""
        if self._pause_preview_s is None:
            if self._resume_at is None or self._program is None:
                return 0.0
            legs = self._make_resume_legs()
            t = self.t_sim_s + self._legs_remaining_s() + legs[0].tl.total_s
            self._pause_preview_s = legs[0].tl.total_s + (legs[1].build(t).total_s if len(legs) > 1 else 0.0)
        return self._pause_preview_s

    def _plate_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The plate as a box in the work-object frame (top-face corner at x min, y min; z up)."""
        sx, sy, sz = (float(v) for v in np.asarray(self.cell.plate_size_mm, dtype=float).reshape(3))
        return np.array([0.0, 0.0, -sz]), np.array([sx, sy, 0.0])
