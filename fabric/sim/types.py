"""Small value types the twin reports (events, pose, extrusion, temperatures, time) and its constants."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fabric.robot.kinematics import IK_OK, IK_SINGULAR

__all__ = ["EVENT_KINDS", "IK_ACCEPT", "STATES", "Event", "ExtrusionState", "Pose", "Temps", "TimeInfo"]

STATES = ("idle", "ready", "printing", "paused", "stopped", "fault", "interrupted")
EVENT_KINDS = ("started", "layer", "paused", "resumed", "stopped", "finished",
               "fault", "temp_reached", "home", "interrupted", "recovered", "stall", "at_layer",
               "override", "calibrated", "interlock", "plate_cleared", "jogged", "extruded")
IK_ACCEPT = (IK_OK, IK_SINGULAR)   # a solution is returned


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

