"""Turns leg specs into timelines with the one motion model (deterministic: same spec, same timeline)."""
from __future__ import annotations

from typing import Any

import numpy as np

from fabric.motion.program import Program, mini_program
from fabric.motion.timeline import Timeline
from fabric.motion.timing import StartState, stop_timeline, time_program
from fabric.sim.config import TwinConfig
from fabric.sim.legs import AuxLegSpec, LegSpec, PoseSpec, ProgramLegSpec, ProgramStart, StopLegSpec
from fabric.sim.state import TwinState
from fabric.wire.codec import pack

__all__ = ["LegBuilder"]


class LegBuilder:
    """Times legs for the twin: program legs with the live heaters and overrides of their start
    (then frozen into the spec), stop legs from their parent, the twin's own moves as given."""

    def __init__(self, robot: Any, config: TwinConfig, state: TwinState) -> None:
        self.robot = robot
        self.config = config
        self.state = state

    def build(self, spec: LegSpec, t0: float, *, freeze: bool = True,
              cache: dict[bytes, Timeline] | None = None) -> Timeline:
        """The timeline of ``spec`` for a leg starting at ``t0`` (``freeze``: record the live inputs
        a program leg used, so a saved copy rebuilds the same; ``cache``: reuse equal specs on restore)."""
        key = pack(spec.to_dict()) if cache is not None else b""
        if cache is not None and key in cache:
            return cache[key]
        if isinstance(spec, ProgramLegSpec):
            start = spec.frozen or self.program_start(spec, t0)
            if freeze:
                spec.frozen = start
            tl = self.time_from(spec, start)
        elif isinstance(spec, StopLegSpec):
            parent = self.build(spec.parent, t0, freeze=freeze, cache=cache)
            stop_tl, _row, _s = stop_timeline(parent, spec.tau_s)
            # a stop leg is only made from a stop that moves, and the same inputs give the same stop
            assert stop_tl is not None, "a stop leg rebuilt to no motion"
            tl = stop_tl
        else:
            tl = self.aux(spec)
        if cache is not None:
            cache[key] = tl
        return tl

    def program_start(self, spec: ProgramLegSpec, t0: float) -> ProgramStart:
        """The inputs of a program leg starting now: pose, a copy of the heaters, the overrides."""
        st = self.state
        pose = spec.pose
        if pose is None:
            ss = StartState.at_joints(self.robot, self.program.wobj, st.rest_q_rad)
            pose = PoseSpec(ss.q_rad, ss.xyz_mm, ss.quat_wxyz)
        return ProgramStart(float(t0), pose, st.thermal.copy(), st.speed_r, st.flow_r)

    def time_from(self, spec: ProgramLegSpec, start: ProgramStart) -> Timeline:
        """Time the program from ``spec.row`` with the given inputs."""
        ss = StartState(start.pose.q_rad, start.pose.xyz_mm, start.pose.quat_wxyz, spec.s_mm, spec.v_mm_s,
                        start.thermal.copy(), start.t0_s)
        return time_program(self.program, self.robot, start.speed_r, spec.row, ss,
                            accel_mm_s2=self.config.accel_mm_s2, flow_r=start.flow_r,
                            retract_speed_mm_s=self.config.retract_speed_mm_s)

    def aux(self, spec: AuxLegSpec) -> Timeline:
        """Time the twin's own rows from their start pose."""
        s = spec.start
        thermal = spec.thermal.copy() if spec.thermal is not None else None
        return time_program(mini_program(spec.rows, spec.wobj, nq=self.robot.nq), self.robot,
                            start_state=StartState(np.asarray(s.q_rad), np.asarray(s.xyz_mm),
                                                   np.asarray(s.quat_wxyz), thermal=thermal, t0_s=spec.t0_s),
                            accel_mm_s2=self.config.accel_mm_s2,
                            retract_speed_mm_s=self.config.retract_speed_mm_s)

    @property
    def program(self) -> Program:
        program = self.state.program
        assert program is not None, "a program leg needs a loaded program"
        return program
