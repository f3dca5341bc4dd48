"""The digital twin: runs a loaded program in simulated time with the print state machine.

States: ``idle`` (nothing loaded, or a job just finished), ``ready`` (a
validated program is loaded), ``printing``, ``paused``, ``stopped``, ``fault``.
Commands change the state at once; the motion they cause then runs in
simulated time, and :meth:`Twin.advance` reports what physically happened as
:class:`Event` s, in order, with their exact times (never rounded to a step).

The motion itself (the queue of legs, the controlled stop, pause, resume and
override re-timing) lives in :mod:`fabric.sim.legs`; the value types
reported here in :mod:`fabric.sim.types`.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from fabric.errors import (
    CollisionError,
    FabricError,
    StateError,
    UnreachableError,
    ValidationError,
)
from fabric.sim.calibration import CalibrationResult, calibrate_plate
from fabric.sim.deposition import Deposition
from fabric.robot.frames import R_from_quat, inv_T, make_T, quat_from_R, rot_x
from fabric.motion.timing import (
    DEFAULT_RETRACT_SPEED_MM_S,
    StartState,
    mini_program,
    time_program,
    validate_program,
)
from fabric.motion.program import MOVEJ, Program
from fabric.motion.thermal import Thermal
from fabric.motion.timeline import Leg, Sample
from fabric.sim.legs import TwinLegs
from fabric.sim.types import (
    EVENT_KINDS,
    STATES,
    Event,
    ExtrusionState,
    Pose,
    Temps,
    TimeInfo,
)
from fabric.sim.types import IK_ACCEPT as _IK_ACCEPT

__all__ = ["EVENT_KINDS", "STATES", "Event", "ExtrusionState", "Pose", "Temps", "TimeInfo", "Twin"]


class Twin(TwinLegs):
    """A simulated cell running one job at a time (see this module's and :mod:`fabric.sim.legs`' docstrings)."""

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
    def speed_r(self) -> float:
        """Live speed override (1 = programmed speeds)."""
        return self._speed_r

    @property
    def flow_r(self) -> float:
        """Live flow override (1 = programmed flow)."""
        return self._flow_r

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

    # ------------------------------------------------------------------ faults

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

    def _command(self, fn: Callable[[], None]) -> None:
        """Run a command's motion planning; a failure there (e.g. an unreachable lift) is a fault."""
        try:
            fn()
        except FabricError as err:
            self._fault(f"{err.code}: {err.message}", self._pending)
        self._sample_key = None

    def _plate_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The plate as a box in the work-object frame (top-face corner at x min, y min; z up)."""
        sx, sy, sz = (float(v) for v in np.asarray(self.cell.plate_size_mm, dtype=float).reshape(3))
        return np.array([0.0, 0.0, -sz]), np.array([sx, sy, 0.0])
