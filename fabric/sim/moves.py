"""Plans the twin's own motion: pause and stop, resume, re-timing after an override, homing.

Pause is a controlled stop: the TCP keeps following the path and slows at the
acceleration limit (extruding with flow tied to the speed, as a synchronised
extruder does), so the stop point lies a little beyond where the command came;
during a joint move or a retraction the row is finished first; a dwell or a
heat-up is interrupted and redone on resume. Then extruder off, retract, and a
straight lift of ``lift_mm`` along the plate normal. Resume goes back down at
``resume_speed_mm_s`` to the recorded point, unretracts and continues the row
from rest. Stop is the same controlled stop, then retract and lift, heaters
off. An override re-times the program after the running row (a heat-up whose
set point changed is redone from now).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from fabric.motion.program import BED, MOVEJ, MOVEL, NOZZLE, RETRACT, SET_TEMP, WAIT, WAIT_TEMP
from fabric.motion.timing import stop_timeline
from fabric.robot.frames import R_from_quat, inv_T, make_T, quat_from_R
from fabric.robot.kinematics import ik_reason
from fabric.schemas.states import Station
from fabric.sim.builder import LegBuilder
from fabric.sim.config import TwinConfig
from fabric.sim.legs import AuxLegSpec, Leg, PoseSpec, ProgramLegSpec, StopLegSpec
from fabric.sim.runner import LegRunner
from fabric.sim.state import ResumePoint, TwinState
from fabric.sim.types import IK_ACCEPT
from fabric.wire.errors import UnreachableError, ValidationError

__all__ = ["MotionPlanner", "RestartPath", "RestartPoint"]


@dataclass(frozen=True)
class RestartPoint:
    """Where a restart goes on: program row ``row``, from ``pose`` (where the row before it ends, or, for a row
    a stop cut short, the spot ``s_mm`` along the row where its bead ends)."""

    row: int
    pose: PoseSpec
    s_mm: float = 0.0


@dataclass(frozen=True)
class RestartPath:
    """The motion of a restart at a layer before it prints: a joint move from ``q_from_rad`` (where the
    robot rests) to ``q_above_rad``, ``xyz_above_mm`` (plate frame) above the point where it goes on
    (:class:`RestartPoint`), then straight down to ``q_down_rad`` there. ``target`` is that point's pose."""

    q_from_rad: np.ndarray
    q_above_rad: np.ndarray
    xyz_above_mm: np.ndarray
    q_down_rad: np.ndarray
    target: PoseSpec
    row: int                   # the program row it goes on with (from ``target``)


class MotionPlanner:
    """Builds and queues the legs of pause, stop, resume, re-timing and homing on ``state``."""

    def __init__(self, robot: Any, home_q_rad: np.ndarray, config: TwinConfig, state: TwinState,
                 builder: LegBuilder, runner: LegRunner) -> None:
        self.robot = robot
        self.home_q_rad = np.asarray(home_q_rad, dtype=float).copy()
        self.config = config
        self.state = state
        self.builder = builder
        self.runner = runner
        self.pause_preview_s: float | None = None      # cache: a resume's duration, if it came now

    def forget_previews(self) -> None:
        """Drop cached durations (the queue, the overrides or the heaters changed)."""
        self.pause_preview_s = None
        for leg in self.state.legs:
            leg.preview_s = None

    # Legs of the twin's own moves -------------------------------------------------------

    def aux_leg(self, rows: list[dict[str, Any]], start: PoseSpec, wobj: np.ndarray, end_kinds: list[str],
                heaters: bool = False) -> Leg:
        """A timed leg of the twin's own rows from ``start`` (plate frame ``wobj``); ``heaters``: it waits
        for set points, timed from the heaters now (the leg must start now)."""
        thermal = self.state.thermal.copy() if heaters else None
        spec = AuxLegSpec(rows, start, np.asarray(wobj, dtype=float), thermal, self.state.t_sim_s)
        return Leg(spec, False, end_kinds, tl=self.builder.aux(spec))

    def home_leg(self) -> Leg:
        """A joint move from where the queue ends to the cell's home joints."""
        start, wobj = self.queue_end()
        home = self.home_q_rad
        Th = inv_T(wobj) @ np.asarray(self.robot.fk(home[None]))[0]
        row = {"op": MOVEJ, "q_rad": home, "xyz_mm": Th[:3, 3], "quat_wxyz": quat_from_R(Th[:3, :3]),
               "vel_r": self.config.home_vel_r}
        return self.aux_leg([row], start, wobj, ["home"])

    def _lift_leg(self, start: PoseSpec, wobj: np.ndarray, end_kind: str) -> Leg:
        """Retract (unless already retracted) and move straight up ``lift_mm`` along the plate normal."""
        cfg, job = self.config, self.state.job
        here = {"q_rad": start.q_rad, "xyz_mm": start.xyz_mm, "quat_wxyz": start.quat_wxyz}
        rows: list[dict[str, Any]] = []
        job.pause_retract_mm = 0.0
        if cfg.retract_mm > 0 and not self._retracted_after_queue():
            rows.append({"op": RETRACT, "value": -cfg.retract_mm, **here})
            job.pause_retract_mm = cfg.retract_mm
        if cfg.lift_mm > 0:
            up = np.asarray(start.xyz_mm, dtype=float) + [0.0, 0.0, cfg.lift_mm]
            rows.append({"op": MOVEL, "q_rad": self._ik_one(wobj, up, start.quat_wxyz, start.q_rad),
                         "xyz_mm": up, "quat_wxyz": start.quat_wxyz, "speed_mm_s": cfg.resume_speed_mm_s})
        if not rows:
            rows.append({"op": WAIT, "value": 0.0, **here})
        return self.aux_leg(rows, start, wobj, [end_kind])

    def ik_one(self, wobj: np.ndarray, xyz: np.ndarray, quat: np.ndarray, seed: np.ndarray) -> np.ndarray:
        """Joints putting the TCP at ``xyz`` / ``quat`` (plate frame ``wobj``) nearest ``seed``
        (UnreachableError, saying why, when none)."""
        return self._ik_one(wobj, xyz, quat, seed)

    def _ik_one(self, wobj: np.ndarray, xyz: np.ndarray, quat: np.ndarray, seed: np.ndarray) -> np.ndarray:
        T = wobj @ make_T(R_from_quat(quat), xyz)
        q, status = self.robot.ik(T[None], np.asarray(seed, dtype=float))
        code = int(np.asarray(status).reshape(-1)[0])
        if code not in IK_ACCEPT:
            raise UnreachableError(f"pose {np.round(xyz, 3).tolist()} mm (plate frame) is unreachable "
                                   f"({ik_reason(code)})", reason=ik_reason(code), gcode_line=-1,
                                   xyz_mm=np.asarray(xyz, dtype=float).tolist())
        return np.asarray(q, dtype=float).reshape(-1, len(seed))[0]

    # Where the queue ends -------------------------------------------------------------

    def queue_end(self) -> tuple[PoseSpec, np.ndarray]:
        """Joints and TCP (plate frame) where the queued motion ends, and that plate frame."""
        st = self.state
        legs = st.legs
        if legs and legs[-1].tl is not None:
            return legs[-1].end_pose(), legs[-1].tl.program.wobj
        wobj = st.program.wobj if st.program is not None else st.work_T
        if legs:                                    # a lazy program leg: it ends on the last row
            p = st.program
            assert p is not None, "a program leg without a loaded program"
            return PoseSpec(p.q_rad[-1], p.xyz_mm[-1], p.quat_wxyz[-1]), wobj
        Tp = inv_T(wobj) @ st.rest_T
        return PoseSpec(st.rest_q_rad.copy(), Tp[:3, 3].copy(), quat_from_R(Tp[:3, :3])), wobj

    def _retracted_after_queue(self) -> bool:
        r = self.state.job.retracted
        for leg in self.state.legs:
            if leg.tl is None:
                continue
            p, rows = leg.tl.program, leg.tl.rows[leg.done:(leg.n_rows or leg.tl.n)]
            rr = rows[p.op[rows] == RETRACT]
            if len(rr):
                r = bool(p.value[rr[-1]] < 0)
        return r

    # Pause and stop -----------------------------------------------------------------------

    def halt(self, end_kind: str) -> None:
        """Controlled stop of the running motion, then retract and lift (pause and stop)."""
        st = self.state
        head = st.legs[0]
        tau = min(max(st.t_sim_s - head.t0, 0.0), head.t_cut)
        queue: list[Leg] = []
        if head.main:
            tl = head.timeline
            j = head.row_at(tau)
            r = tl.start_row + j
            op = tl.program.op[r]
            if op == MOVEL and tl.len_mm[j] > 0:
                head.cut_at(tau)
                stop_tl, row, s = stop_timeline(tl, tau)
                if stop_tl is not None:
                    stop_leg = Leg(StopLegSpec(head.spec, tau), True, [], tl=stop_tl)
                    stop_leg.partial_end = row == stop_tl.start_row + stop_tl.n - 1
                    queue.append(stop_leg)
            elif op in (WAIT, WAIT_TEMP):
                head.cut_at(tau)
                row, s = r, 0.0
            else:
                head.cut_after(j)
                row, s = r + 1, 0.0
            head.end_kinds = []
            pose = (queue[-1] if queue else head).end_pose()
            st.job.resume_at = ResumePoint(row, s, pose)
        elif {"paused", "stopped"} & set(head.end_kinds):
            # still lifting from the previous pause: cancel the queued resume, keep lifting
            st.legs = [head]
            head.end_kinds = [end_kind]
            self.pause_preview_s = None
            return
        else:
            # going back down to resume: that resume never completes; lift again from where it ends
            head.end_kinds = []
            pose = head.end_pose()
        wobj = (queue[-1] if queue else head).timeline.program.wobj
        st.legs = [head] + queue
        st.legs.append(self._lift_leg(pose, wobj, end_kind))
        self.pause_preview_s = None

    # Interlock ----------------------------------------------------------------------------

    def interlock_pause(self, j: int, reason: str) -> None:
        """Pause before local row ``j`` of the running program leg (which would extrude cold): the leg
        ends where the row would start, the print is paused there (retract, lift) and goes on from
        that row on resume."""
        st = self.state
        head = st.legs[0]
        head.cut_before(j)
        head.end_kinds = []
        tl = head.timeline
        smp = tl.sample(head.t_cut)
        pose = PoseSpec(np.asarray(smp.q_rad, float), np.asarray(smp.xyz_mm, float),
                        np.asarray(smp.quat_wxyz, float))
        st.job.resume_at = ResumePoint(tl.start_row + j, 0.0, pose)
        st.state, st.reason = Station.PAUSED, reason
        st.legs = [head, self._lift_leg(pose, tl.program.wobj, "paused")]
        self.pause_preview_s = None

    # Instant stop -------------------------------------------------------------------------

    def stop_dead(self, t: float, events: list) -> ResumePoint | None:
        """Stop the running motion dead at ``t`` (a crashed controller): the rows up to ``t`` are
        processed, the row in progress keeps its volume so far, the robot rests where it was.

        Returns where the program would go on (the point reached inside the running program
        row), or None when no program leg was running (the queue is dropped either way)."""
        st = self.state
        legs = st.legs
        if not legs or not legs[0].placed:
            st.legs = []
            return None
        head = legs[0]
        tau = min(max(t - head.t0, 0.0), head.t_cut)
        self.runner.run_leg(head, tau, False, events)
        head.cut_at(tau)
        head.end_kinds = []
        st.legs = [head]
        point = None
        if head.main:
            tl = head.timeline
            j = head.n_rows - 1
            r = tl.start_row + j
            smp = tl.sample(tau)
            pose = PoseSpec(np.asarray(smp.q_rad, float), np.asarray(smp.xyz_mm, float),
                            np.asarray(smp.quat_wxyz, float))
            if not head.partial_end:
                point = ResumePoint(r + 1, 0.0, pose)
            elif tl.program.op[r] == MOVEL:
                point = ResumePoint(r, float(smp.s_mm), pose)
            else:                                   # a joint move, dwell, heat-up or retraction: redo it
                point = ResumePoint(r, 0.0, pose)
        self.runner.finish_leg(head, events)
        st.legs = []
        self.pause_preview_s = None
        return point

    # Resume -------------------------------------------------------------------------------

    def _resume_legs(self, end_kind: str = "resumed") -> list[Leg]:
        st = self.state
        at = st.job.resume_at
        assert at is not None and st.program is not None
        start, wobj = self.queue_end()
        back = {"q_rad": at.pose.q_rad, "xyz_mm": at.pose.xyz_mm, "quat_wxyz": at.pose.quat_wxyz}
        rows: list[dict[str, Any]] = [{"op": MOVEL, **back, "speed_mm_s": self.config.resume_speed_mm_s}]
        if st.job.pause_retract_mm > 0:
            rows.append({"op": RETRACT, "value": st.job.pause_retract_mm, **back})
        down = self.aux_leg(rows, start, wobj, [end_kind])
        if at.row >= len(st.program):
            down.end_kinds.append("finished")
            return [down]
        spec = ProgramLegSpec(at.row, PoseSpec(at.pose.q_rad, at.pose.xyz_mm, at.pose.quat_wxyz), at.s_mm, 0.0)
        return [down, Leg(spec, True, ["finished"])]

    def resume(self, end_kind: str = "resumed") -> None:
        """Queue the way back to the resume point, the unretraction and the rest of the program
        (``end_kind``: the event fired when the nozzle is back on the path)."""
        for leg in self._resume_legs(end_kind):
            self.runner.enqueue(leg)
        self.state.job.pause_retract_mm = 0.0
        self.pause_preview_s = None

    # Starting at a layer -------------------------------------------------------------------

    def layer_start_row(self, layer: int) -> int:
        """The first program row of ``layer`` (0-based, as in events)."""
        p = self.state.program
        assert p is not None, "no program loaded"
        rows = np.flatnonzero(p.layer == layer)
        if layer < 0 or not len(rows):
            top = int(p.layer.max())
            raise ValidationError(f"the program has no layer {layer + 1} (layers 1 to {top + 1})", field="from_layer",
                                  layers=top + 1)
        return int(rows[0])

    def row_point(self, row: int) -> RestartPoint:
        """Going on at the start of ``row``: from where the row before it ends."""
        p = self.state.program
        assert p is not None, "no program loaded"
        return RestartPoint(row, PoseSpec(p.q_rad[row - 1], p.xyz_mm[row - 1], p.quat_wxyz[row - 1]))

    def cut_point(self, row: int, end_mm: np.ndarray) -> RestartPoint:
        """Going on along ``row`` from ``end_mm`` (plate frame), where a stop cut its bead short."""
        p = self.state.program
        assert p is not None, "no program loaded"
        _, wobj = self.queue_end()
        q = self._ik_one(wobj, np.asarray(end_mm, dtype=float), p.quat_wxyz[row], p.q_rad[row - 1])
        s_mm = float(np.linalg.norm(np.asarray(end_mm, dtype=float) - p.xyz_mm[row - 1]))
        return RestartPoint(row, PoseSpec(q, np.asarray(end_mm, dtype=float).copy(), p.quat_wxyz[row].copy()), s_mm)

    def restart_path(self, point: RestartPoint) -> RestartPath:
        """Where a restart at ``point`` goes before printing (what :meth:`restart_at` queues, and what the
        station has certified first): from where the queue ends, a joint move to ``lift_mm`` (at least 1 mm)
        above the point, then straight down onto it."""
        st, cfg = self.state, self.config
        p = st.program
        assert p is not None, "no program loaded"
        start, wobj = self.queue_end()
        target = point.pose
        above = np.asarray(target.xyz_mm, dtype=float) + [0.0, 0.0, max(cfg.lift_mm, 1.0)]
        q_above = self._ik_one(wobj, above, target.quat_wxyz, target.q_rad)
        return RestartPath(start.q_rad.copy(), q_above, above, np.asarray(target.q_rad, dtype=float).copy(), target,
                           point.row)

    def restart_at(self, point: RestartPoint, end_kind: str) -> None:
        """Go on with the program from ``point`` as a print restarted at a layer does: the heaters to the set
        points the program has there (waiting for them), a joint move to ``lift_mm`` above the point,
        straight down, then the program from there (:meth:`restart_path`). ``end_kind`` fires once down."""
        st, cfg = self.state, self.config
        p = st.program
        assert p is not None, "no program loaded"
        start, wobj = self.queue_end()
        path = self.restart_path(point)
        row = point.row
        target = path.target
        rows: list[dict[str, Any]] = []
        here = {"q_rad": start.q_rad, "xyz_mm": start.xyz_mm, "quat_wxyz": start.quat_wxyz}
        for heater in (NOZZLE, BED):
            sets = np.flatnonzero((p.op[:row] == SET_TEMP) & (p.aux[:row] == heater))
            if len(sets):
                value = float(p.value[sets[-1]])
                rows.append({"op": SET_TEMP, "aux": heater, "value": value, **here})
                if value > 0:
                    rows.append({"op": WAIT_TEMP, "aux": heater, "value": value, **here})
        rows.append({"op": MOVEJ, "q_rad": path.q_above_rad, "xyz_mm": path.xyz_above_mm,
                     "quat_wxyz": target.quat_wxyz, "vel_r": cfg.home_vel_r})
        rows.append({"op": MOVEL, "q_rad": path.q_down_rad, "xyz_mm": target.xyz_mm, "quat_wxyz": target.quat_wxyz,
                     "speed_mm_s": cfg.resume_speed_mm_s})
        self.runner.enqueue(self.aux_leg(rows, start, wobj, [end_kind], heaters=True))
        self.runner.enqueue(Leg(ProgramLegSpec(row, target, point.s_mm, 0.0), True, ["finished"]))
        self.pause_preview_s = None

    def restart_move(self, point: RestartPoint) -> tuple[np.ndarray, np.ndarray]:
        """Joints where the robot rests and joints above ``point`` (the restart's joint move)."""
        path = self.restart_path(point)
        return path.q_from_rad, path.q_above_rad

    # Overrides --------------------------------------------------------------------------

    def retime(self, temp_changed: bool) -> None:
        """Re-time the program after the running row (or redo a heat-up whose set point changed)."""
        st = self.state
        head = st.legs[0]
        tl = head.timeline
        p = tl.program
        tau = min(max(st.t_sim_s - head.t0, 0.0), head.t_cut)
        j = head.row_at(tau)
        r = tl.start_row + j
        pose = PoseSpec(p.q_rad[r], p.xyz_mm[r], p.quat_wxyz[r])
        if p.op[r] == WAIT_TEMP and temp_changed:
            head.cut_at(tau)
            nxt, v = r, 0.0
        elif j >= tl.n - 1:
            return
        else:
            head.cut_after(j)
            nxt = r + 1
            v = float(tl.v1_mm_s[j]) if p.op[r] == MOVEL else 0.0
        head.end_kinds = []
        st.legs = [head, Leg(ProgramLegSpec(nxt, pose, 0.0, v), True, ["finished"])]

    # Time left ----------------------------------------------------------------------------

    def remaining_s(self) -> float:
        """Simulated time until the queued motion ends (lazy legs timed as if they started next)."""
        total, t = 0.0, self.state.t_sim_s
        for k, leg in enumerate(self.state.legs):
            if k == 0 and leg.placed:
                rem = leg.t0 + leg.t_cut - t
            elif leg.tl is not None:
                rem = leg.t_cut if leg.n_rows else leg.tl.total_s
            else:
                if leg.preview_s is None:
                    leg.preview_s = self.builder.build(leg.spec, t + total, freeze=False).total_s
                rem = leg.preview_s
            total += max(rem, 0.0)
        return total

    def resume_preview_s(self) -> float:
        """Time a resume would take from now (the resume moves plus the rest of the program)."""
        st = self.state
        if self.pause_preview_s is None:
            if st.job.resume_at is None or st.program is None:
                return 0.0
            legs = self._resume_legs()
            t = st.t_sim_s + self.remaining_s() + legs[0].timeline.total_s
            rest = self.builder.build(legs[1].spec, t, freeze=False).total_s if len(legs) > 1 else 0.0
            self.pause_preview_s = legs[0].timeline.total_s + rest
        return self.pause_preview_s
