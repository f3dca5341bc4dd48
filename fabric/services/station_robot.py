"""The station's robot: a controller that follows the twin, and the twin as its shadow.

Each tick of the station's clock (:meth:`RobotLink.tick`, on the writer's thread) the link

1. fills the controller's reference with the twin's commanded joints ``LOOKAHEAD_S`` ahead of now (the
   running leg's; a pause, a stop or a new move replaces what was ahead from now on);
2. reads the control steps streamed since the last tick, with the measured joints: each step's TCP deviation
   from the commanded path around it, through the cell's kinematics (the nozzle's tip), into the run's
   figures (:class:`~fabric.drivers.deviation.DeviationStats`);
3. says what the station must do: interrupt the print when the controller faulted or the connection was
   lost, pause it when the deviation exceeded the cell's bound.

The twin's time follows the reference the robot consumed (:meth:`advance_s`): when the reference ran dry
(the station stalled longer than the lookahead) the robot stood at its last sample, and the twin's time
goes on from there, not from the wall clock, so the path never jumps.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from fabric import schemas as s
from fabric.drivers.controller import Controller, ControllerInfo, ControllerStatus
from fabric.drivers.deviation import DeviationStats, path_deviation_mm
from fabric.drivers.reference import Reference
from fabric.robot.frames import inv_T, quat_from_R
from fabric.schemas.states import Station
from fabric.sim.twin import Twin
from fabric.sim.types import Pose
from fabric.wire.errors import RobotError

__all__ = ["RobotLink", "LinkAction", "LOOKAHEAD_S", "SAMPLE_S", "DEFAULT_BOUND_MM"]

LOOKAHEAD_S = 0.25          # the reference reaches this far ahead of now (a tick is 20 ms; a loaded host stalls)
SAMPLE_S = 0.004            # spacing of the reference's samples (the controller interpolates between them)
STATUS_EVERY = 5            # the controller's status is read every this many ticks (100 ms)
DEFAULT_BOUND_MM = 0.5
PATH_BEHIND_S = 0.1         # a step's deviation is its distance to the commanded path from this long before it
PATH_AHEAD_S = 0.05         # to this long after it (the arm trails its reference by 15-25 ms, or leads it)
JUMP_RAD = 0.02             # a new window of the reference this far from the one being followed is not sent
RUNAWAY_R = 20.0            # a deviation this many bounds away, in any motion: the robot is stopped (interrupt)
JOINT_TIME_R = 0.35
"""While it drives a robot the twin times its joint moves 1/JOINT_TIME_R as long on the same paths, and its
linear moves within JOINT_TIME_R**2 of the TCP acceleration (Twin.time_for_robot). Measured on franky-sim: the
fr3 home move at Franka's published limits (0.73 s) made the joint impedance controller oscillate to 134 deg
off under FR3's torque rate limit, at half the speed it followed within 0.43 deg in most runs and ran away in
one; a 50 mm descent at 175 mm/s braking at 2000 mm/s2 ran 10.7 mm off. At 0.35 the margin is wider."""


@dataclass(frozen=True)
class LinkAction:
    """What the station does after a tick: ``interrupt`` (a fault) or ``pause`` (off the path), and why."""

    kind: str
    reason: str


class RobotLink:
    """A controller driven from the twin's timeline. Used on the station's writer thread only."""

    def __init__(self, controller: Controller, twin: Twin, bound_mm: float = DEFAULT_BOUND_MM,
                 log: logging.Logger | None = None) -> None:
        self.controller = controller
        self.address = controller.address
        self.robot = twin.robot
        self.bound_mm = float(bound_mm)
        self.log = log or logging.getLogger("station.robot")
        self.reference = Reference(len(np.asarray(twin.pose().q_rad)))
        self.info: ControllerInfo | None = None
        self.last_status = ControllerStatus(self.address, connected=False)
        self.connect_error = ""
        self.run = DeviationStats()
        self.tick_max_mm = 0.0
        self.q_meas_rad: np.ndarray | None = None
        self._ticks = 0
        self.jumped = ""
        self._was_moving = False
        self._ref_end_s = float("nan")       # the last reference sample's time (monotonic) of a moving twin

    # --- connecting ---------------------------------------------------------------------------

    def connect(self, twin: Twin) -> ControllerInfo:
        """Connect, make the twin stand where the robot stands, and follow it (before the clock runs)."""
        info = self.reconnect()
        self.attach(twin)
        return info

    def reconnect(self) -> ControllerInfo:
        """Connect, or reconnect and clear the controller's errors (any thread: it may take the connect
        deadline; it touches no twin). A RobotError says why not."""
        try:
            info = self.controller.recover() if self.info is not None else self.controller.connect()
        except RobotError as err:
            self.connect_error = err.message
            self.last_status = ControllerStatus(self.address, connected=False, fault=err.message)
            raise
        self.info, self.connect_error, self.q_meas_rad = info, "", info.q_rad.copy()
        self.last_status = self.controller.status()
        self.log.info("robot %s connected (server version %s)", self.address, info.server_version)
        return info

    @property
    def ready(self) -> bool:
        """Connected, following, no error and no fault: motion commands may run."""
        st = self.last_status
        return self.info is not None and st.ok and st.following

    def attach(self, twin: Twin) -> None:
        """(The writer's) the twin at rest stands where the robot stands; the robot follows the twin."""
        if self.info is None:
            raise RobotError(f"robot {self.address}: not connected", robot=self.address, reason="lost")
        q = self.controller.status().q_rad
        q = self.info.q_rad if q is None else q
        if not twin.moving:
            twin.stand_at(q)
        self._was_moving = False
        self.reference.hold(twin.pose().q_rad, time.monotonic())
        self.controller.follow(self.reference)
        self.last_status = self.controller.status()
        self.log.info("robot %s follows the twin", self.address)

    def gate(self, command: str) -> None:
        """(The writer's) before a motion command: refused with the reason unless the robot is ready."""
        self.last_status = self.controller.status()
        if self.ready:
            return
        st = self.last_status
        why = st.fault or self.connect_error or ("errors: " + ", ".join(st.errors) if st.errors else "") or \
            ("not connected" if not st.connected else "not following the twin")
        reason = "fault" if (st.errors or (st.fault and not st.lost)) else "lost"
        raise RobotError(f"{command} refused: robot {self.address}: {why}; `fabric-cli recover` connects again "
                         "and clears its errors where that is safe", robot=self.address, reason=reason)

    # --- the clock ----------------------------------------------------------------------------

    def advance_s(self, now: float, last: float) -> float:
        """Simulated seconds this tick: the wall time since the last, but no further than the reference the
        robot had (it stood at its end meanwhile)."""
        end = self._ref_end_s
        if self._was_moving and np.isfinite(end) and end < now:
            self.log.warning("the robot's reference ran dry %.3f s ago: the twin goes on from where it stood",
                             now - end)
            return max(0.0, end - last)
        return now - last

    def tick(self, twin: Twin, now: float, row: int, gcode_line: int, extruding: bool) -> LinkAction | None:
        """Feed the reference, read the steps and the status; what the station must do, if anything. The bound
        holds while the extruder lays a bead; any motion that runs away (``RUNAWAY_R`` bounds) is stopped."""
        self._feed(twin, now)
        self._measure(twin, row, gcode_line, extruding)
        self._ticks += 1
        if self._ticks % STATUS_EVERY == 0 or self.last_status.fault:
            self.last_status = self.controller.status()
        st = self.last_status
        if self.jumped:
            why, self.jumped = self.jumped, ""
            return LinkAction("interrupt", f"robot {self.address}: {why}")
        if self.tick_max_mm > RUNAWAY_R * self.bound_mm and self.last_status.following:
            return LinkAction("interrupt", f"robot {self.address}: the arm ran {self.tick_max_mm:.1f} mm off its "
                                           "commanded path: stopped")
        if (st.fault or st.lost or st.errors) and self.info is not None:
            why = st.fault or ("errors: " + ", ".join(st.errors))
            if twin.state.in_print and twin.state != Station.INTERRUPTED:
                return LinkAction("interrupt", f"robot {self.address}: {why}")
        if self.tick_max_mm > self.bound_mm and extruding and twin.state == Station.PRINTING:
            return LinkAction("pause", f"the nozzle left its path by {self.tick_max_mm:.2f} mm (bound "
                                       f"{self.bound_mm:g} mm) at G-code line {gcode_line}: paused")
        return None

    def _feed(self, twin: Twin, now: float) -> None:
        moving = twin.moving
        if moving:
            offs = np.arange(0.0, LOOKAHEAD_S + SAMPLE_S / 2, SAMPLE_S)
            q = twin.commanded_q(twin.t_sim_s + offs)
            if q is None:                   # a command queued a move, timed at the next step: what is ahead stays
                return
            if self.reference.last() is not None:
                was = self.reference.at(now)[0]
                jump = float(np.abs(q[0] - was).max())
                if jump > JUMP_RAD:         # never sent: the arm holds what it had, and the print is interrupted
                    self.jumped = (f"the commanded path jumped by {np.degrees(jump):.1f} deg at t_sim "
                                   f"{twin.t_sim_s:.3f} s ({twin.state}, {len(twin.s.legs)} legs): not sent")
                    self.log.error("%s", self.jumped)
                    return
            self.reference.put(now + offs, q)
            self._ref_end_s = now + offs[-1]
        elif self._was_moving or self.reference.last() is None:
            self.reference.hold(twin.pose().q_rad, now)
            self._ref_end_s = float("nan")
        if moving and not self._was_moving:
            self.run = DeviationStats()              # a run starts: its own figures
        self._was_moving = moving

    def _measure(self, twin: Twin, row: int, gcode_line: int, extruding: bool) -> None:
        """The steps' deviations; a run's figures count the steps that laid a bead (what the bound is about)."""
        tr = self.controller.tracking()
        self.tick_max_mm = 0.0
        if not len(tr):
            return
        # the commanded path around these steps (the reference holds a second behind and its lookahead ahead)
        path = self.reference.between(float(tr.t_s[0]) - PATH_BEHIND_S, float(tr.t_s[-1]) + PATH_AHEAD_S)
        dev = path_deviation_mm(self.robot.tcp_xyz_mm(tr.q_meas_rad), self.robot.tcp_xyz_mm(path))
        self.q_meas_rad = tr.q_meas_rad[-1].copy()
        self.tick_max_mm = float(dev.max())
        if twin.moving and extruding:
            self.run.add(dev, twin.t_sim_s, row, gcode_line)
        self.run.last_mm = float(dev[-1])

    # --- what the station shows -----------------------------------------------------------------

    def pose(self, twin: Twin) -> Pose | None:
        """The measured pose (joints, TCP in the plate frame and the base frame), or None before any."""
        if self.q_meas_rad is None:
            return None
        T = np.asarray(self.robot.fk(self.q_meas_rad[None]))[0]
        Tp = inv_T(twin.work_object_T) @ T
        return Pose(self.q_meas_rad.copy(), Tp[:3, 3].copy(), quat_from_R(Tp[:3, :3]), T[:3, 3].copy())

    def status_key(self) -> tuple:
        """What of the robot's status a watcher must see at once (a change publishes the state)."""
        st = self.last_status
        return (st.connected, st.lost, st.following, st.mode, tuple(st.errors), st.fault, self.connect_error)

    def status_msg(self) -> s.RobotStatus:
        st = self.last_status
        return s.RobotStatus(address=self.address, connected=st.connected and not st.lost, following=st.following,
                             mode=st.mode, server_version=int(st.server_version or 0), errors=list(st.errors),
                             fault=st.fault or self.connect_error, deviation_mm=round(self.run.last_mm, 4),
                             deviation_max_mm=round(self.run.worst.mm, 4), bound_mm=self.bound_mm)

    def deviation_msg(self, seq: int, t_sim_s: float) -> s.Deviation:
        w = self.run.worst
        return s.Deviation(seq=seq, t_sim_s=t_sim_s, now_mm=round(self.run.last_mm, 4),
                           tick_max_mm=round(self.tick_max_mm, 4), p50_mm=round(self.run.quantile_mm(0.5), 4),
                           p99_mm=round(self.run.quantile_mm(0.99), 4), max_mm=round(w.mm, 4), steps=self.run.n,
                           row=w.row, gcode_line=w.gcode_line, bound_mm=self.bound_mm)

    def halt(self) -> None:
        """Stop the robot where it is (the controller's stop): it follows nothing until it is attached again."""
        self.controller.stop()
        self.last_status = self.controller.status()

    def close(self) -> None:
        self.controller.close()
