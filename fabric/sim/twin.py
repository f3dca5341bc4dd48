"""The digital twin: runs a loaded program in simulated time with the print state machine.

States: ``idle`` (nothing loaded, or a job just finished), ``ready`` (a
validated program is loaded), ``printing``, ``paused``, ``stopped``, ``fault``.
Commands change the state at once; the motion they cause then runs in
simulated time, and :meth:`Twin.advance` reports what physically happened as
:class:`Event` s, in order, with their exact times (never rounded to a step).

The twin is composed of small collaborators around one state object:

- :class:`~fabric.sim.state.TwinState` holds everything that changes (saved
  by :meth:`Twin.snapshot`, brought back by :meth:`Twin.from_snapshot`);
- :class:`~fabric.sim.builder.LegBuilder` times motion legs from their specs;
- :class:`~fabric.sim.runner.LegRunner` walks legs in simulated time (row
  events, heaters, beads);
- :class:`~fabric.sim.moves.MotionPlanner` plans pause, stop, resume,
  re-timing and homing.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from fabric.motion.program import MOVEL, Program
from fabric.motion.thermal import Thermal
from fabric.motion.validate import validate_program
from fabric.robot.frames import make_T, rot_x
from fabric.robot.kinematics import ik_reason
from fabric.robot.time_scaled import TimeScaledRobot
from fabric.schemas.states import FREE_STATION_STATES, IN_PRINT_STATES, Station
from fabric.sim import manual
from fabric.sim.builder import LegBuilder
from fabric.sim.calibration import CalibrationResult, calibrate_plate
from fabric.sim.config import TwinConfig
from fabric.sim.deposition import Deposition
from fabric.sim.legs import Leg, ProgramLegSpec
from fabric.sim.material import DepositGuard, PlateMaterial
from fabric.sim.moves import MotionPlanner, RestartPoint
from fabric.sim.readout import Readout
from fabric.sim.runner import DepositTrip, Interlock, LegRunner
from fabric.sim.state import JobState, TwinState
from fabric.sim.types import EVENT_KINDS, IK_ACCEPT, STATES, Event, ExtrusionState, Pose, Temps, TimeInfo
from fabric.wire.errors import CollisionError, FabricError, StateError, UnreachableError, ValidationError

SPEED_R_MIN, SPEED_R_MAX = 0.0, 10.0         # speed and flow overrides: (0, 10]
CUT_MM = 1e-3                                # a bead ending this far short of its row's end was cut there

__all__ = ["EVENT_KINDS", "STATES", "Event", "ExtrusionState", "Pose", "Temps", "TimeInfo", "Twin", "TwinConfig"]


class Twin:
    """A simulated cell running one job at a time (see the module docstring)."""

    def __init__(self, cell: Any, config: TwinConfig | None = None, *, thermal: Thermal | None = None,
                 state: TwinState | None = None, **settings: Any) -> None:
        """``settings`` are :class:`TwinConfig` fields (``accel_mm_s2=...``) when no ``config`` is given."""
        if config is not None and settings:
            raise ValidationError("give either a TwinConfig or its settings", field="config")
        self.cell = cell
        self.robot = cell.robot
        self.config = config if config is not None else TwinConfig(**settings)
        if state is None:
            q_home = np.asarray(cell.home_q_rad, dtype=float).copy()
            state = TwinState(work_T=np.asarray(cell.wobj_T(), dtype=float).copy(), rest_q_rad=q_home,
                              rest_T=np.asarray(self.robot.fk(q_home[None]))[0],
                              rng=np.random.default_rng(self.config.rng_seed),
                              thermal=thermal.copy() if thermal is not None else Thermal())
        self.s = state
        self.builder = LegBuilder(self.robot, self.config, state)
        self.runner = LegRunner(state, self.builder)
        self.moves = MotionPlanner(self.robot, cell.home_q_rad, self.config, state, self.builder, self.runner)
        self.readout = Readout(self.config, state, self.moves)

    # ------------------------------------------------------------------ saving

    def snapshot(self, with_beads: bool = True) -> dict[str, Any]:
        """The twin's settings and whole state as plain values and arrays (msgpack-able with
        :func:`fabric.wire.codec.pack`). The loaded program is named by its row count only; ``with_beads``
        False leaves out the bead arrays (kept apart by a checkpoint that stores them incrementally)."""
        return {"config": self.config.to_dict(), "state": self.s.to_dict(with_beads)}

    @classmethod
    def from_snapshot(cls, cell: Any, snapshot: dict[str, Any], program: Program | None,
                      beads: dict[str, np.ndarray] | None = None) -> Twin:
        """A twin in exactly the state ``snapshot`` saved, running ``program`` (the same one), with
        ``beads`` when the snapshot was taken without them."""
        config = TwinConfig.from_dict(snapshot["config"])
        state = TwinState.from_dict(snapshot["state"], program, beads)
        twin = cls(cell, config, state=state)
        cache: dict[bytes, Any] = {}
        for leg in state.legs:
            if leg.placed or _timed_at_creation(leg):
                leg.tl = twin.builder.build(leg.spec, leg.t0, cache=cache)
                leg.derive()
        return twin

    # ------------------------------------------------------------------ queries

    @property
    def state(self) -> Station:
        """Lifecycle state (one of :data:`STATES`)."""
        return self.s.state

    @property
    def reason(self) -> str:
        """Why the twin is in its state (human-readable)."""
        return self.s.reason

    @property
    def t_sim_s(self) -> float:
        """Simulated time since the twin was built."""
        return self.s.t_sim_s

    @property
    def beads(self) -> Deposition:
        """Beads deposited by the current (or last) job."""
        return self.s.beads

    @property
    def work_object_T(self) -> np.ndarray:
        """The plate frame in the base frame as the twin believes it (updated by :meth:`calibrate`)."""
        return self.s.work_T.copy()

    @property
    def program(self) -> Program | None:
        """The loaded program (None when nothing is loaded)."""
        return self.s.program

    @property
    def speed_r(self) -> float:
        """Live speed override (1 = programmed speeds)."""
        return self.s.speed_r

    @property
    def flow_r(self) -> float:
        """Live flow override (1 = programmed flow)."""
        return self.s.flow_r

    @property
    def moving(self) -> bool:
        """True while any motion (program, pause/stop moves, homing) is still to run."""
        return bool(self.s.legs)

    def pose(self) -> Pose:
        """Where the robot is now (commanded pose of the twin)."""
        return self.readout.pose()

    def extrusion(self) -> ExtrusionState:
        """Extruder on/off and flow now; volume and filament pushed since start (retractions included)."""
        return self.readout.extrusion()

    def temps(self) -> Temps:
        """Nozzle and bed temperatures now (closed form: exact at any step)."""
        return self.readout.temps()

    def time_info(self) -> TimeInfo:
        """Elapsed, expected total and remaining simulated time of the job (paused: if resumed now)."""
        return self.readout.time_info()

    def commanded_q(self, t_sim_s: np.ndarray) -> np.ndarray | None:
        """The commanded joints (M, nq) at simulated times ``t_sim_s`` (M,) from now on: the running leg's,
        held at its end past it (the next leg is timed when it starts); the pose at rest when nothing runs;
        None when a leg was queued since the last step and is not timed yet."""
        return self.readout.commanded_q(np.asarray(t_sim_s, dtype=float))

    def time_for_robot(self, r: float) -> None:
        """Time every motion from now on for a real robot's controller: joint moves ``1/r`` as long on the same
        path (joint limits scaled by r, r**2, r**3: :class:`~fabric.robot.time_scaled.TimeScaledRobot`), linear
        moves within ``r**2`` of the TCP acceleration (the programmed speeds stay, as far as the joints allow)."""
        self.builder.robot = TimeScaledRobot(self.robot, r) if r < 1.0 else self.robot
        self.builder.config = dataclasses.replace(self.config, accel_mm_s2=self.config.accel_mm_s2 * r * r)

    def stand_at(self, q_rad: np.ndarray) -> None:
        """The robot stands at ``q_rad`` (a real robot's measured joints when the station connects to it):
        the twin at rest takes that pose, so every move it plans next starts where the robot is."""
        if self.moving:
            raise StateError("the robot is moving: it stands nowhere yet", state=self.state, command="stand_at")
        q = np.asarray(q_rad, dtype=float).reshape(-1)
        self.s.rest_q_rad, self.s.rest_T = q.copy(), np.asarray(self.robot.fk(q[None]))[0]
        self.readout.forget()

    # ------------------------------------------------------------------ commands

    def _refuse(self, command: str, allowed: tuple[Station, ...]) -> None:
        if self.state not in allowed:
            raise StateError(f"cannot {command} while {self.state}", state=self.state, command=command,
                             allowed=[a.value for a in allowed])

    def _busy(self, command: str) -> None:
        if self.s.legs:
            raise StateError(f"cannot {command} while the robot is moving", state=self.s.state, command=command,
                             reason="moving")

    def _check_hot(self, command: str) -> None:
        """Refuse to go on printing with the nozzle below the material's minimum extrusion temperature."""
        min_c = self.runner.min_extrude_c()
        nozzle_c = self.s.thermal.temp_at(0, self.s.t_sim_s)
        if min_c is not None and nozzle_c < min_c and self.s.thermal.target(0) < min_c:
            raise StateError(f"cannot {command}: the nozzle is at {nozzle_c:.0f} C and set to "
                             f"{self.s.thermal.target(0):.0f} C, below the material's minimum extrusion temperature "
                             f"{min_c:.0f} C: raise its set point first", state=self.s.state, command=command,
                             nozzle_c=nozzle_c, min_c=min_c)

    def _new_job(self, program: Program) -> None:
        st = self.s
        st.job = JobState()
        st.beads = Deposition(program)
        self.moves.forget_previews()

    def load(self, program: Program) -> TimeInfo:
        """Validate ``program`` and make it the job (state ``ready``); returns the time estimate."""
        st = self.s
        self._refuse("load", FREE_STATION_STATES)
        self._busy("load")                 # e.g. a stop's lift: its end event belongs to the job before
        validate_program(program, self.robot)
        dp = np.abs(program.wobj - st.work_T)
        if dp[:3, 3].max() > 0.01 or dp[:3, :3].max() > 1e-6:
            raise ValidationError("the program was planned for another work object than the twin's: re-plan it "
                                  "for the current (calibrated) work object", field="wobj",
                                  program_wobj=program.wobj, twin_wobj=st.work_T)
        previous = st.program
        st.program = program
        try:
            estimate = self.builder.build(ProgramLegSpec(0), st.t_sim_s, freeze=False).total_s
        except FabricError:
            st.program = previous
            raise
        st.estimate_s = estimate
        self._new_job(program)
        st.speed_r = st.flow_r = 1.0       # speed and flow overrides belong to a job: the next one starts at 1
        st.t_started_s = st.t_ended_s = None
        st.state, st.reason = Station.READY, f"loaded {len(program)} rows"
        return TimeInfo(0.0, estimate, estimate, estimate)

    def start(self, from_layer: int | None = None, collision_ok: bool = True) -> None:
        """Run the loaded program from its start (again, after a stop or a finished print); or, with
        ``from_layer`` (0-based), restart it at that
        layer on the part already on the plate (after a stop, or a finished print to add to): heat,
        joint move above the layer's first point, down, go on. The deposit record is kept then.
        ``collision_ok``: the collision service's verdict on that joint move."""
        st = self.s
        self._refuse("start", FREE_STATION_STATES)
        if st.program is None:
            raise StateError(f"cannot start while {st.state}: no program loaded", state=st.state, command="start")
        self._busy("start")
        point = self.restart_point(from_layer) if from_layer is not None else None
        row = point.row if point is not None else 0
        if not collision_ok:
            raise CollisionError("the move to the layer was refused by the collision check", command="start")
        if point is None or row == 0:
            self._new_job(st.program)
            self.runner.guard = None
            leg = Leg(ProgramLegSpec(0), True, ["finished"])
            self.runner.enqueue(leg)
            st.estimate_s = leg.timeline.total_s
            reason = "started"
        else:
            st.job.resume_at = None
            st.job.carry_mm3.clear()
            self._guard_run(row + 1 if point.s_mm > 0 else row)     # a cut row goes on along what it laid
            self.moves.restart_at(point, "at_layer")
            st.estimate_s = self.moves.remaining_s()
            reason = f"restarted at layer {from_layer + 1}" if from_layer is not None else "restarted"
        st.t_started_s, st.t_ended_s = st.t_sim_s, None
        st.state, st.reason = Station.PRINTING, reason
        data = {"rows": len(st.program), "estimate_s": st.estimate_s, "from_row": row,
                "from_layer": from_layer if from_layer is not None else 0}
        self.runner.emit(st.pending, st.t_sim_s, "started", data)

    def restart_point(self, layer: int) -> RestartPoint:
        """Where a restart at ``layer`` (0-based) goes on: the layer's first row; or, where the part on the plate
        has beads of that layer already (a print stopped in it), where its last bead ends (along the row a stop
        cut short, or at the next row): the restart goes on where the part ends, not through the layer's first
        part again. Refused (ValidationError) for a layer with nothing left to print (the part has it all)."""
        p = self.s.program
        if p is None:
            raise StateError("no program loaded", state=self.state, command="start")
        row = self.moves.layer_start_row(layer)
        at = self.s.job.resume_at
        if at is not None and self.s.job.carry_mm3 and int(p.layer[at.row]) == layer:
            return self.moves.cut_point(at.row, at.pose.xyz_mm)       # an interrupted row: where it stopped
        beads = self.s.beads
        laid = np.flatnonzero(beads.layer == layer) if len(beads) else np.zeros(0, np.int64)
        if not len(laid):
            return self.moves.row_point(row)
        last = int(laid[np.argmax(beads.row[laid])])
        r = int(beads.row[last])
        end = np.asarray(beads.end_mm[last], dtype=float)
        if np.linalg.norm(end - p.xyz_mm[r]) > CUT_MM:               # a stop cut that row short: go on along it
            return self.moves.cut_point(r, end)
        extruding = np.flatnonzero((p.op == MOVEL) & (p.flow_mm3_mm > 0) & (p.layer >= layer))
        if not len(extruding) or extruding[-1] <= r:
            raise ValidationError(f"layer {layer + 1} is printed to its end and no layer follows it: nothing is left "
                                  f"to print", field="from_layer", from_layer=layer + 1)
        return self.moves.row_point(max(row, r + 1))

    def layer_move(self, from_layer: int) -> tuple[np.ndarray, np.ndarray]:
        """Joints where the robot rests and joints above the first point of ``from_layer`` (for a
        collision check of a restart there)."""
        if self.s.program is None:
            raise StateError("no program loaded", state=self.s.state, command="start")
        return self.moves.restart_move(self.restart_point(from_layer))

    def pause(self, reason: str = "paused by operator") -> None:
        """Controlled stop, extruder off, retract, lift; ``paused`` event once the robot is clear."""
        self._refuse("pause", (Station.PRINTING,))
        self.s.state, self.s.reason = Station.PAUSED, reason
        self._command(lambda: self.moves.halt("paused"))

    def resume(self) -> None:
        """Back down to the stop point, unretract, continue the program from there (refused while the
        nozzle is below the material's minimum extrusion temperature)."""
        self._refuse("resume", (Station.PAUSED,))
        self._check_hot("resume")
        self.s.state, self.s.reason = Station.PRINTING, "resuming"
        self._command(self.moves.resume)

    def stop(self) -> None:
        """Abort: controlled stop, retract, lift, heaters off; the beads printed stay on record."""
        st = self.s
        self._refuse("stop", IN_PRINT_STATES)
        was = st.state
        st.state, st.reason = Station.STOPPED, "stopped by operator"
        for h in (0, 1):
            st.thermal.set_target(h, 0.0, st.t_sim_s)
        if was == Station.PRINTING:
            self._command(lambda: self.moves.halt("stopped"))
        elif st.legs:
            st.legs[-1].end_kinds = ["stopped" if k == "paused" else k for k in st.legs[-1].end_kinds]
        else:
            self.runner.on_end("stopped", st.t_sim_s, st.pending)

    def clear_plate(self) -> None:
        """The part was taken off the plate: its beads are forgotten (the job's totals stay on record)."""
        self._refuse("clear_plate", FREE_STATION_STATES)
        self._busy("clear_plate")
        self.s.beads = Deposition(self.s.program)

    def go_home(self, collision_ok: bool = True) -> None:
        """Joint move to the cell's home joints (``collision_ok``: the collision service's verdict)."""
        self._refuse("go_home", FREE_STATION_STATES)
        if not collision_ok:
            raise CollisionError("the home move was refused by the collision check", command="go_home")
        self.runner.enqueue(self.moves.home_leg())
        self.readout.forget()
        self.s.reason = "homing"

    def jog_move(self, dxyz_mm: list[float] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(joints now, joints of each point of the jog (M, nq), the last its end) of a jog by ``dxyz_mm``
        (plate frame), for the collision check before it is made; refused as :meth:`jog` would be."""
        self._refuse("jog", FREE_STATION_STATES)
        self._busy("jog")
        plan = manual.jog_plan(self.moves, dxyz_mm)
        return np.asarray(plan.start.q_rad, dtype=float), plan.q_rad

    def jog(self, dxyz_mm: list[float] | np.ndarray, speed_mm_s: float) -> None:
        """A straight move by ``dxyz_mm`` in the plate frame at ``speed_mm_s``, the nozzle's orientation kept
        (while not printing; the station has certified it against the part first)."""
        self._refuse("jog", FREE_STATION_STATES)
        self._busy("jog")
        self.runner.enqueue(manual.jog_leg(self.moves, manual.jog_plan(self.moves, dxyz_mm), speed_mm_s))
        self.readout.forget()
        self.s.reason = "jogging"

    def extrude(self, length_mm: float, feed_mm_s: float) -> None:
        """Push (> 0) or pull back (< 0) ``length_mm`` of filament at ``feed_mm_s``, the robot still; refused
        with the nozzle below the minimum extrusion temperature (the loaded material's, else firmware's)."""
        if not math.isfinite(length_mm) or length_mm == 0.0:
            raise ValidationError("give a non-zero filament length", field="length_mm", value=length_mm)
        self._refuse("extrude", FREE_STATION_STATES)
        self._busy("extrude")
        min_c = self.runner.min_extrude_c() if self.s.program is not None else manual.FIRMWARE_MIN_EXTRUDE_C
        nozzle_c = self.s.thermal.temp_at(0, self.s.t_sim_s)
        if min_c is not None and nozzle_c < min_c:
            raise StateError(f"cannot extrude: the nozzle is at {nozzle_c:.0f} C, below the minimum extrusion "
                             f"temperature {min_c:.0f} C: heat it first (fabric-cli override --nozzle 210, or e "
                             f"to preheat in the console)",
                             state=self.s.state, command="extrude", nozzle_c=nozzle_c, min_c=min_c)
        self.runner.enqueue(manual.extrude_leg(self.moves, length_mm, feed_mm_s, self.config.retract_speed_mm_s))
        self.readout.forget()
        self.s.reason = "extruding" if length_mm > 0 else "retracting"

    def interrupt(self, reason: str) -> None:
        """The controller died at the current instant (a crashed station, restored from its checkpoint
        and advanced to its last recorded time): the robot stops dead where it was, the extruder stops.

        A print (printing or paused) becomes ``interrupted`` with the point where it goes on; the row
        in progress keeps its volume so far, so :meth:`recover` deposits no bead twice and none is
        missing. A stop whose lift was cut short ends as stopped; other states keep their state, with
        the robot resting where its move was cut."""
        st = self.s
        events = st.pending
        was = st.state
        t = st.t_sim_s
        point = self.moves.stop_dead(t, events)
        self.readout.forget()
        if point is not None:
            st.job.resume_at = point
        st.job.extruder_on = False
        if was.in_print and st.job.resume_at is not None:
            if not st.job.retracted:
                st.job.pause_retract_mm = 0.0        # the pause's retraction had not happened yet
            at = st.job.resume_at
            st.state, st.reason = Station.INTERRUPTED, reason
            # what the print deposited so far travels with the event (the job's record shows it)
            self.runner.emit(events, t, "interrupted", {"reason": reason, "resume_row": at.row,
                                                        "resume_s_mm": at.s_mm, "xyz_mm": at.pose.xyz_mm.tolist(),
                                                        **self.runner.totals(t)})
        elif was == Station.STOPPED and st.t_ended_s is None:
            self.runner.on_end("stopped", t, events)

    def recover(self, collision_ok: bool = True, from_layer: int | None = None) -> None:
        """Go on with an interrupted print: back to the interrupted spot, unretract, continue; or, with
        ``from_layer``, restart at that layer's first point instead (the row cut short becomes a partial
        bead). ``collision_ok``: the collision service's verdict on the move back."""
        st = self.s
        self._refuse("recover", (Station.INTERRUPTED,))
        point = self.restart_point(from_layer) if from_layer is not None else None
        if not collision_ok:
            raise CollisionError("the move back to the interrupted spot was refused by the collision check",
                                 command="recover")
        st.state, st.reason = Station.PRINTING, "recovering"
        if point is None:
            at = st.job.resume_at
            self._guard_run(at.row + 1 if at is not None else 0)       # the row cut short goes on where it was
            self._command(lambda: self.moves.resume("recovered"))
            return
        self.runner.record_partial()
        self._guard_run(point.row + 1 if point.s_mm > 0 else point.row)
        self._command(lambda: self.moves.restart_at(point, "recovered"))

    @property
    def resume_row(self) -> int | None:
        """The row an interrupted (or paused) print goes on from, cut short where it stopped; None: none kept."""
        at = self.s.job.resume_at
        return None if at is None else int(at.row)

    def recovery_move(self, from_layer: int | None = None) -> tuple[np.ndarray, np.ndarray] | None:
        """Joints where the robot rests and joints it goes to first to recover (the interrupted spot, or
        above ``from_layer``'s first point), for a collision check; None when nothing is interrupted."""
        at = self.s.job.resume_at
        if self.state != Station.INTERRUPTED or at is None:
            return None
        if from_layer is not None:
            return self.layer_move(from_layer)
        return self.s.rest_q_rad.copy(), np.asarray(at.pose.q_rad, dtype=float).copy()

    def note(self, kind: str, data: dict[str, Any] | None = None) -> None:
        """Record an event of the cell around the twin (e.g. the station stalled) in the twin's event
        sequence; it is reported by the next :meth:`advance`."""
        self.runner.emit(self.s.pending, self.s.t_sim_s, kind, data)

    def number_events_after(self, seq: int) -> None:
        """Go on numbering events after ``seq`` (a fresh twin continuing a station's event log)."""
        self.s.seq = max(self.s.seq, int(seq))

    def trip(self, reason: str) -> None:
        """Put the twin in ``fault`` now (e.g. a monitor saw something wrong): instant stop."""
        self._fault(reason, self.s.pending)

    def set_overrides(self, speed_r: float | None = None, flow_r: float | None = None,
                      nozzle_c: float | None = None, bed_c: float | None = None) -> None:
        """Live overrides. Speed and flow take effect from the next row (the rest is re-timed);
        set points at once (a heat-up in progress is re-timed)."""
        st = self.s
        for name, val in (("speed_r", speed_r), ("flow_r", flow_r)):
            if val is not None and (not math.isfinite(val) or not SPEED_R_MIN < val <= SPEED_R_MAX):
                raise ValidationError(f"{name} must be in ({SPEED_R_MIN:g}, {SPEED_R_MAX:g}], got {val}", field=name)
        for heater, val in ((0, nozzle_c), (1, bed_c)):
            if val is not None:
                st.thermal.check_target(heater, float(val))
        min_c = self.runner.min_extrude_c()
        if (nozzle_c is not None and min_c is not None and 0.0 < nozzle_c < min_c
                and self.state.print_on):
            raise ValidationError(f"nozzle set point {nozzle_c:g} C is below the material's minimum extrusion "
                                  f"temperature {min_c:g} C (0 switches the heater off)", field="nozzle_c",
                                  min_c=min_c)
        temp = False                                   # everything checked: nothing is changed by a refusal
        for heater, val in ((0, nozzle_c), (1, bed_c)):
            if val is not None:
                st.thermal.set_target(heater, float(val), st.t_sim_s)
                temp = True
        if speed_r is not None:
            st.speed_r = float(speed_r)
        if flow_r is not None:
            st.flow_r = float(flow_r)
        self.moves.forget_previews()
        if self.state.printing and st.legs and st.legs[0].main:
            self._command(lambda: self.moves.retime(temp))

    def calibrate(self) -> CalibrationResult:
        """Probe the plate, fit its true frame and make it the work object (see calibration module).

        A program loaded before is unloaded (state ``idle``): it must be re-planned for the new frame."""
        st = self.s
        self._refuse("calibrate", FREE_STATION_STATES)
        self._busy("calibrate")
        lo, hi = self._plate_box()
        res, _plan, frames = calibrate_plate(st.work_T, np.asarray(self.cell.true_wobj_T(), float), lo, hi,
                                            self.config.probe_noise_mm, st.rng)
        T = make_T(frames[:, :3, :3] @ rot_x(np.pi), res.points_base_mm)
        _q, status = self.robot.ik(T, st.rest_q_rad)
        bad = ~np.isin(np.asarray(status), IK_ACCEPT)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            reason = ik_reason(np.asarray(status)[i])
            raise UnreachableError(f"probe {i} at {np.round(res.points_base_mm[i], 2).tolist()} mm is unreachable "
                                   f"({reason})", probe=i, reason=reason, gcode_line=-1)
        st.work_T = res.work_object_T.copy()
        if self.state == Station.READY:
            st.program = None
            st.state, st.reason = Station.IDLE, "calibrated: re-plan the program for the new work object"
        return res

    # ------------------------------------------------------------------ simulation

    def advance(self, dt_sim_s: float) -> list[Event]:
        """Move simulated time forward by exactly ``dt_sim_s``; every event that happened, in order."""
        if not math.isfinite(dt_sim_s) or dt_sim_s < 0:
            raise ValidationError(f"dt_sim_s must be finite and >= 0, got {dt_sim_s}", field="dt_sim_s")
        st = self.s
        t_target = st.t_sim_s + dt_sim_s
        events, st.pending = st.pending, []
        t_here = st.t_sim_s
        try:
            while st.legs:
                leg = st.legs[0]
                end = leg.t0 + leg.t_cut
                final = t_target >= end
                t_here = end if final else t_target
                self.runner.run_leg(leg, leg.t_cut if final else t_target - leg.t0, final, events)
                if isinstance(self.runner.tripped, DepositTrip):
                    self._deposit_guarded(events)
                    continue                       # faulted before the row: nothing runs on
                if self.runner.tripped is not None:
                    self._interlocked(events)
                    continue                       # the leg now ends where the cold row would start
                if not final:
                    break
                self.runner.finish_leg(leg, events)
        except FabricError as err:
            self._fault(f"{err.code}: {err.message}", events, t_here)
        st.t_sim_s = t_target
        self.readout.forget()
        return events

    # ------------------------------------------------------------------ faults

    def _interlocked(self, events: list[Event]) -> None:
        """The runner refused to start extruding cold: pause there (a clear reason, an event)."""
        trip, self.runner.tripped = self.runner.tripped, None
        assert isinstance(trip, Interlock), "called only when the interlock tripped"
        self.moves.interlock_pause(trip.j, trip.reason)
        self.runner.emit(events, trip.t_s, "interlock", {"reason": trip.reason, "nozzle_c": trip.nozzle_c,
                                                         "min_c": trip.min_c, "row": trip.row})
        self.readout.forget()

    def _deposit_guarded(self, events: list[Event]) -> None:
        """The last guard saw the next row lay its bead into the part on the plate: fault there, before it."""
        trip, self.runner.tripped = self.runner.tripped, None
        assert isinstance(trip, DepositTrip), "called only when the guard tripped"
        self.runner.guard = None                   # the run ends here
        self._fault(trip.reason, events, trip.t_s)
        self.runner.tripped = None

    def _guard_run(self, first_row: int) -> None:
        """Arm the last guard for a run of the loaded program from ``first_row`` on the beads now on the plate
        (a restart at a layer, a recovery); a run with the plate clear needs none."""
        st = self.s
        self.runner.guard = None
        if st.program is not None and len(st.beads):
            material = PlateMaterial.from_arrays(st.beads.to_arrays(0))
            self.runner.guard = DepositGuard.of(st.program, first_row, material, st.beads)

    def _fault(self, reason: str, events: list[Event], t: float | None = None) -> None:
        """Instant stop at ``t`` (default now), extruder and heaters off, state ``fault``."""
        st = self.s
        self.readout.forget()
        t = st.t_sim_s if t is None else t
        if st.legs and st.legs[0].placed:
            leg = st.legs[0]
            tau = min(max(t - leg.t0, 0.0), leg.t_cut)
            try:
                self.runner.run_leg(leg, tau, False, events)
                leg.cut_at(tau)
                leg.end_kinds = []
                st.legs = [leg]
                self.runner.finish_leg(leg, events)
            except FabricError as err:          # the twin stops anyway; say why the pose may be stale
                reason = f"{reason} (stopping at the fault point failed: {err.message})"
        st.legs = []
        st.job.extruder_on = False
        for h in (0, 1):
            st.thermal.set_target(h, 0.0, t)
        self.runner.record_partial()
        if st.t_started_s is not None and st.t_ended_s is None:
            st.t_ended_s = t
        st.state, st.reason = Station.FAULT, reason
        self.runner.emit(events, t, "fault", {"reason": reason})

    def _command(self, fn: Callable[[], None]) -> None:
        """Run a command's motion planning; a failure there (e.g. an unreachable lift) is a fault."""
        try:
            fn()
        except FabricError as err:
            self._fault(f"{err.code}: {err.message}", self.s.pending)
        self.readout.forget()

    def _plate_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The plate as a box in the work-object frame (top-face corner at x min, y min; z up)."""
        sx, sy, sz = (float(v) for v in np.asarray(self.cell.plate_size_mm, dtype=float).reshape(3))
        return np.array([0.0, 0.0, -sz]), np.array([sx, sy, 0.0])


def _timed_at_creation(leg: Leg) -> bool:
    """Legs of the twin's own moves and stop legs were timed when queued (program legs when placed)."""
    return not isinstance(leg.spec, ProgramLegSpec)
