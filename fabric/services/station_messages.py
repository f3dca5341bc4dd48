"""The station's wire messages, built from its twin and its job's metadata.

:class:`StationMessages` owns what the station's streams carry: the sequence
numbers of the pose and extrusion streams, the gates that decide when the
sampled streams are published (:mod:`fabric.services.telemetry_gate`), and the
state message with the key that decides when it is. Every method is called with
the station's lock held (the twin is not thread-safe).
"""
from __future__ import annotations

import time

import numpy as np

from fabric import schemas as s
from fabric.motion.program import MOVEL
from fabric.robot.frames import T_to_xyzrpy
from fabric.schemas.states import Station
from fabric.services.station_robot import RobotLink
from fabric.services.telemetry_gate import EXTRUSION_PERIOD_S, TEMPS_PERIOD_S, ChangeOrPeriod
from fabric.sim.twin import Twin
from fabric.sim.types import ExtrusionState
from fabric.store.journal import StationMeta

__all__ = ["StationMessages", "JOB_EVENTS"]

JOB_EVENTS = ("started", "layer", "paused", "resumed", "recovered", "finished", "stopped", "fault", "interrupted",
              "override")


class StationMessages:
    """Messages of one station's twin (``twin`` and ``meta`` are the station's, for its whole life)."""

    def __init__(self, twin: Twin, meta: StationMeta) -> None:
        self.twin, self.meta = twin, meta
        self.seq_pose = 0                    # the last pose sample's number (a position reply carries it)
        self.seq_extrusion = 0
        self._extrusion_gate = ChangeOrPeriod(EXTRUSION_PERIOD_S)
        self._temps_gate = ChangeOrPeriod(TEMPS_PERIOD_S)
        self._planned: tuple[int, np.ndarray] | None = None     # (program, its planned volume up to each row)
        self.seq_deviation = 0
        self.robot: RobotLink | None = None     # the robot the station drives: poses are its measured ones

    def follow_robot(self, robot: RobotLink) -> None:
        """Poses from now on are the robot's measured ones, and the state says how the robot is."""
        self.robot = robot

    def event(self, ev) -> s.Event:
        """The wire event; a job's events name the job and its simulated time so far."""
        data = dict(ev.data)
        if ev.kind in JOB_EVENTS and self.meta.job_id:
            data.setdefault("job_id", self.meta.job_id)
            t0 = self.twin.s.t_started_s
            data.setdefault("elapsed_s", ev.t_sim_s - t0 if t0 is not None else 0.0)
        return s.Event(seq=ev.seq, t_sim_s=ev.t_sim_s, kind=ev.kind, row=ev.row, gcode_line=ev.gcode_line,
                       layer=ev.layer, data=data)

    def pose(self, sample: bool = False) -> s.Pose:
        """The twin's pose now; ``sample``: it is the pose stream's next sample (numbered)."""
        if sample:
            self.seq_pose += 1
        p = self.robot.pose(self.twin) if self.robot is not None else None
        p = p if p is not None else self.twin.pose()
        return s.Pose(seq=self.seq_pose, t_sim_s=self.twin.t_sim_s, q_deg=np.degrees(p.q_rad).tolist(),
                      xyz_mm=list(map(float, p.xyz_mm)), quat_wxyz=list(map(float, p.quat_wxyz)),
                      base_xyz_mm=list(map(float, p.base_xyz_mm)), wall_time_s=time.time())

    def extrusion_due(self, now: float, e: ExtrusionState) -> s.Extrusion | None:
        """The extrusion message if it is to be published now (its own sequence: a gap is a lost message)."""
        key = (bool(e.on), round(float(e.flow_mm3_s), 3), int(e.layer), float(self.twin.flow_r))
        if not self._extrusion_gate.due(key, now):
            return None
        self.seq_extrusion += 1
        return s.Extrusion(seq=self.seq_extrusion, t_sim_s=self.twin.t_sim_s, on=bool(e.on),
                           flow_mm3_s=float(e.flow_mm3_s), extruded_mm3=float(e.extruded_mm3),
                           filament_mm=float(e.filament_mm), layer=int(e.layer), row=int(e.row),
                           gcode_line=int(e.gcode_line), flow_r=float(self.twin.flow_r))

    def temps_due(self, now: float) -> s.Temps | None:
        """The temperatures if they are to be published now."""
        t = self.twin.temps()
        if not self._temps_gate.due((float(t.nozzle_target_c), float(t.bed_target_c)), now):
            return None
        return s.Temps(nozzle_c=float(t.nozzle_c), nozzle_target_c=float(t.nozzle_target_c), bed_c=float(t.bed_c),
                       bed_target_c=float(t.bed_target_c), t_sim_s=self.twin.t_sim_s)

    def progress_r(self, ext: ExtrusionState) -> float:
        """Where the print is in its program: the share of the planned volume in the rows before the one
        running (1 once the print has finished). Not the volume deposited, which a flow override above 1
        brings to the planned total layers before the end."""
        if self.twin.state == Station.IDLE and self.twin.reason == "finished":
            return 1.0
        program = self.twin.program
        if program is None or len(program) == 0:
            return 0.0
        if self._planned is None or self._planned[0] != id(program):
            self._planned = (id(program), np.cumsum(program.flow_mm3_mm * program.path_length_mm()
                                                    * (program.op == MOVEL)))
        cum = self._planned[1]
        row = min(max(int(ext.row), 0), len(cum) - 1)
        done = float(cum[row - 1]) if row > 0 else 0.0
        return min(done / float(cum[-1]), 1.0) if cum[-1] > 0 else 0.0

    def state_key(self, ext: ExtrusionState) -> tuple:
        """What a published state says that matters to a watcher (a change is published at once);
        the first four fields changing also force a checkpoint."""
        robot = () if self.robot is None else self.robot.status_key()
        return (self.twin.state, self.twin.reason, self.meta.program_id, self.meta.plate_occupied, int(ext.layer),
                self.meta.rtf,
                float(self.twin.speed_r), float(self.twin.flow_r), round(self.progress_r(ext), 3), robot)

    def state(self, ext: ExtrusionState | None = None) -> s.StationState:
        """The station's whole state (``ext``: the twin's extrusion now, when already read)."""
        twin, meta = self.twin, self.meta
        ti = twin.time_info()
        ext = twin.extrusion() if ext is None else ext
        wobj_xyz, wobj_rpy = T_to_xyzrpy(twin.work_object_T)
        return s.StationState(state=twin.state, reason=twin.reason, program_id=meta.program_id,
                              job_id=meta.job_id, t_sim_s=float(twin.t_sim_s), elapsed_s=float(ti.elapsed_s),
                              total_s=float(ti.total_s), remaining_s=float(ti.remaining_s),
                              progress_r=self.progress_r(ext), deposited_mm3=float(ext.extruded_mm3),
                              planned_mm3=meta.planned_mm3, layer=int(ext.layer), layers_total=meta.layers_total,
                              rtf=meta.rtf, speed_r=float(twin.speed_r), flow_r=float(twin.flow_r),
                              wobj_xyz_mm=np.asarray(wobj_xyz).tolist(), wobj_rpy_deg=np.asarray(wobj_rpy).tolist(),
                              plate_clear=not meta.plate_occupied, plate_mm3=float(meta.plate_mm3),
                              plate_job_id=meta.plate_job_id,
                              robot=None if self.robot is None else self.robot.status_msg())
