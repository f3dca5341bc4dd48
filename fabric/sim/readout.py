"""What the twin reports now: pose, extrusion, temperatures and time, read from its state (no changes)."""
from __future__ import annotations

import numpy as np

from fabric.motion.timeline import Sample
from fabric.robot.frames import R_from_quat, inv_T, make_T, quat_from_R
from fabric.schemas.states import Station
from fabric.sim.config import TwinConfig
from fabric.sim.legs import Leg
from fabric.sim.moves import MotionPlanner
from fabric.sim.state import TwinState
from fabric.sim.types import ExtrusionState, Pose, Temps, TimeInfo

__all__ = ["Readout"]


class Readout:
    """Reads the twin's state for telemetry; caches the running leg's sample per simulated instant."""

    def __init__(self, config: TwinConfig, state: TwinState, moves: MotionPlanner) -> None:
        self.config = config
        self.state = state
        self.moves = moves
        self._cache: tuple[tuple[float, int, float], Sample] | None = None
        self._rest: tuple[bytes, Pose] | None = None      # the pose at rest, kept while the robot stands still

    def forget(self) -> None:
        """Drop the cached sample (the state changed other than by time passing)."""
        self._cache = None

    def _now_sample(self) -> tuple[Sample | None, Leg | None]:
        """The running leg's sample now (cached per simulated instant: telemetry reads it often)."""
        legs = self.state.legs
        leg = legs[0] if legs and legs[0].placed else None
        if leg is None:
            return None, None
        key = (self.state.t_sim_s, id(leg), leg.t_cut)
        if self._cache is None or self._cache[0] != key:
            smp = leg.timeline.sample(min(max(self.state.t_sim_s - leg.t0, 0.0), leg.t_cut))
            self._cache = (key, smp)
        return self._cache[1], leg

    def pose(self) -> Pose:
        """Where the robot is now (commanded pose of the twin)."""
        smp, leg = self._now_sample()
        work_T = self.state.work_T
        if smp is None or leg is None:
            return self._rest_pose(work_T)
        wobj = leg.timeline.program.wobj
        if np.array_equal(wobj, work_T):
            return Pose(np.array(smp.q_rad, dtype=float), np.array(smp.xyz_mm, dtype=float),
                        np.array(smp.quat_wxyz, dtype=float), np.array(smp.base_xyz_mm, dtype=float))
        T = wobj @ make_T(R_from_quat(smp.quat_wxyz), smp.xyz_mm)
        Tp = inv_T(work_T) @ T
        return Pose(np.array(smp.q_rad, dtype=float), Tp[:3, 3].copy(), quat_from_R(Tp[:3, :3]), T[:3, 3].copy())

    def commanded_q(self, t_sim_s: np.ndarray) -> np.ndarray | None:
        """The commanded joints at simulated times ``t_sim_s``: the running leg's (held at its cut), or at rest;
        None while the next leg is queued but not timed yet (it is at the next step)."""
        legs = self.state.legs
        if legs and not legs[0].placed:
            return None
        leg = legs[0] if legs else None
        if leg is None:
            return np.tile(np.asarray(self.state.rest_q_rad, dtype=float), (len(t_sim_s), 1))
        tau = np.clip(t_sim_s - leg.t0, 0.0, leg.t_cut)
        return np.asarray(leg.timeline.sample_many(tau).q_rad, dtype=float)

    def _rest_pose(self, work_T: np.ndarray) -> Pose:
        """The pose of the robot standing still, computed once while it stands (telemetry asks every tick)."""
        q, T = np.asarray(self.state.rest_q_rad, dtype=float), np.asarray(self.state.rest_T, dtype=float)
        key = q.tobytes() + T.tobytes() + np.asarray(work_T, dtype=float).tobytes()
        if self._rest is None or self._rest[0] != key:
            Tp = inv_T(work_T) @ T
            self._rest = (key, Pose(q.copy(), Tp[:3, 3].copy(), quat_from_R(Tp[:3, :3]), T[:3, 3].copy()))
        p = self._rest[1]
        return Pose(p.q_rad.copy(), p.xyz_mm.copy(), p.quat_wxyz.copy(), p.base_xyz_mm.copy())

    def extrusion(self) -> ExtrusionState:
        """Extruder on/off and flow now; volume and filament pushed since start (retractions included)."""
        smp, leg = self._now_sample()
        job = self.state.job
        flow, extra = 0.0, 0.0
        if smp is not None and leg is not None and leg.main and smp.extruding:
            flow = smp.flow_mm3_s
            tl = leg.timeline
            j = smp.row - tl.start_row
            if j >= leg.done:   # the row in progress: the part covered so far
                s0 = tl.s0_mm if j == 0 else 0.0
                extra = float(tl.program.flow_mm3_mm[smp.row]) * tl.flow_r * (smp.s_mm - s0)
        vol = job.extruded_mm3 + extra
        program = self.state.program
        g = int(program.gcode_line[job.row]) if program is not None else -1
        filament_mm = vol / self.config.filament_area_for_mm2(program) + job.retract_total_mm
        return ExtrusionState(job.extruder_on, float(flow), vol, filament_mm, job.layer, job.row, g)

    def temps(self) -> Temps:
        """Nozzle and bed temperatures now (closed form: exact at any step)."""
        th, t = self.state.thermal, self.state.t_sim_s
        return Temps(th.temp_at(0, t), th.target(0), th.temp_at(1, t), th.target(1))

    def time_info(self) -> TimeInfo:
        """Elapsed, expected total and remaining simulated time of the job (paused: if resumed now)."""
        st = self.state
        state = st.state
        if state == Station.READY:
            return TimeInfo(0.0, st.estimate_s, st.estimate_s, st.estimate_s)
        if st.t_started_s is None:
            return TimeInfo(0.0, 0.0, 0.0, st.estimate_s)
        end = st.t_ended_s if st.t_ended_s is not None else st.t_sim_s
        elapsed = end - st.t_started_s
        remaining = 0.0
        if state.printing:
            remaining = self.moves.remaining_s()
        elif state.print_on:                          # paused, interrupted
            remaining = self.moves.remaining_s() + self.moves.resume_preview_s()
        return TimeInfo(elapsed, elapsed + remaining, remaining, st.estimate_s)

