"""The twin's motion legs: running them in simulated time, and planning pause, stop, resume and re-timing.

Motion is a queue of *legs*, each a :class:`~fabric.motion.timeline.Timeline`
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

from collections.abc import Callable
from typing import Any

import numpy as np

from fabric.errors import UnreachableError
from fabric.sim.deposition import Deposition
from fabric.robot.frames import R_from_quat, inv_T, make_T, quat_from_R
from fabric.motion.timing import StartState, mini_program, stop_timeline, time_program
from fabric.motion.program import MOVEL, RETRACT, SET_TEMP, WAIT, WAIT_TEMP, Program
from fabric.motion.thermal import HEATER_NAMES, Thermal
from fabric.motion.timeline import Leg, Timeline
from fabric.sim.types import IK_ACCEPT as _IK_ACCEPT
from fabric.sim.types import Event

__all__ = ["TwinLegs"]


class TwinLegs:
    """The leg machinery of :class:`~fabric.sim.twin.Twin` (a mixin: the twin owns the state below)."""

    # configuration and state set up by Twin.__init__ / Twin._reset_job
    robot: Any
    accel_mm_s2: float
    retract_mm: float
    lift_mm: float
    resume_speed_mm_s: float
    retract_speed_mm_s: float
    state: str
    reason: str
    t_sim_s: float
    _work_T: np.ndarray
    _thermal: Thermal
    _program: Program | None
    _beads: Deposition
    _legs: list[Leg]
    _seq: int
    _sample_key: tuple[float, int, float] | None
    _speed_r: float
    _flow_r: float
    _t_started: float | None
    _t_ended: float | None
    _rest_q: np.ndarray
    _rest_T: np.ndarray
    _extruded_done: float
    _retract_total_mm: float
    _retracted: bool
    _carry: dict[int, float]
    _ext_on: bool
    _layer: int
    _row: int
    _resume_at: tuple[int, float, np.ndarray, np.ndarray, np.ndarray] | None
    _pause_retract_mm: float
    _pause_preview_s: float | None

    # ------------------------------------------------------------------ running legs

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

    # ------------------------------------------------------------------ legs

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
