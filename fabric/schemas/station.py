"""Station (digital twin) messages: telemetry, commands and reports.

Small fixed vectors (a pose's 3 coordinates, 6 joints) are plain lists so a
monitor needs nothing but msgpack; bulk data elsewhere is packed arrays.
"""
from __future__ import annotations

from typing import Any

from fabric.schemas.base import f, schema

MESH_FORMATS = ("stl", "glb", "csv")
STATES = ("idle", "ready", "printing", "paused", "stopped", "fault", "moving", "interrupted")


@schema("station.Pose")
class Pose:
    """TCP pose (plate frame and robot base frame) and joints of the twin."""
    seq: int
    t_sim_s: float
    q_deg: list[float]
    xyz_mm: list[float]          # TCP in the plate frame (work object)
    quat_wxyz: list[float]
    base_xyz_mm: list[float]     # TCP in the robot base frame
    wall_time_s: float = 0.0


@schema("station.Extrusion")
class Extrusion:
    seq: int
    t_sim_s: float
    on: bool
    flow_mm3_s: float
    extruded_mm3: float
    filament_mm: float
    layer: int
    row: int
    gcode_line: int
    flow_r: float = 1.0


@schema("station.Temps")
class Temps:
    nozzle_c: float
    nozzle_target_c: float
    bed_c: float
    bed_target_c: float
    t_sim_s: float = 0.0


@schema("station.State", version=3)
class StationState:
    """The station's whole state: a snapshot reply and a publication on change.

    ``t_sim_s`` is the station's simulated clock (the same clock as pose, extrusion and events);
    ``elapsed_s`` the job's simulated time since it started. ``layer`` is the 0-based index of the
    layer being printed, as in events (people read ``layer + 1`` of ``layers_total``).
    ``progress_r`` is the deposited volume over the program's (0 while heating, frozen while paused,
    where it stopped for a stopped print, 1 when finished). ``plate_clear`` is false from the first
    bead of a print until the operator says the part is off the plate (``clear_plate``); ``plate_mm3``
    and ``plate_job_id`` say what is on it."""
    state: str = f(choices=STATES)
    reason: str = ""
    program_id: str = ""
    job_id: str = ""
    t_sim_s: float = 0.0
    elapsed_s: float = 0.0
    total_s: float = 0.0
    remaining_s: float = 0.0
    progress_r: float = f(default=0.0, ge=0.0, le=1.0)
    deposited_mm3: float = 0.0
    planned_mm3: float = 0.0
    layer: int = -1
    layers_total: int = 0
    rtf: float = 1.0
    speed_r: float = 1.0
    flow_r: float = 1.0
    wobj_xyz_mm: list[float] = f(factory=lambda: [0.0, 0.0, 0.0], shape=(3,))    # work object now (calibrated)
    wobj_rpy_deg: list[float] = f(factory=lambda: [0.0, 0.0, 0.0], shape=(3,))
    plate_clear: bool = True
    plate_mm3: float = 0.0
    plate_job_id: str = ""


@schema("station.Event")
class Event:
    """One entry of the lossless event stream (``seq`` has no gaps)."""
    seq: int
    t_sim_s: float
    kind: str
    row: int = -1
    gcode_line: int = -1
    layer: int = -1
    data: dict[str, Any] = f(factory=dict)


@schema("station.EventsQuery", version=2)
class EventsQuery:
    """Events from ``since_seq`` on; ``kinds`` non-empty: only those kinds."""
    since_seq: int = f(default=0, ge=0)
    limit: int = f(default=10000, ge=1, le=100000)
    kinds: list[str] = f(factory=list)


@schema("station.EventList", version=2)
class EventList:
    """Events from the log, oldest first; ``next_seq`` pages on, ``last_seq`` is the newest logged."""
    events: list[Event]
    next_seq: int
    last_seq: int = 0


@schema("station.TimeInfo")
class TimeInfo:
    """Simulation time: elapsed, total, remaining, and the estimate given at load."""
    elapsed_s: float
    total_s: float
    remaining_s: float
    estimate_s: float
    state: str = ""


@schema("station.LoadRequest")
class LoadRequest:
    """Load a planned program, fetched by id from the planner's artifact store."""
    program_id: str = f(max_len=128)
    job_id: str = ""


@schema("station.StartRequest", version=2)
class StartRequest:
    """``rtf`` 1 = real time, larger = faster, 0 = as fast as possible; nil keeps the current one.
    ``from_layer`` (0-based, as in events; -1 = not given): start or recover at that layer."""
    rtf: float | None = f(default=None, ge=0.0, le=1e6)
    from_layer: int = f(default=-1, ge=-1, le=1_000_000)


@schema("station.Overrides")
class Overrides:
    speed_r: float | None = f(default=None, ge=0.05, le=4.0)
    flow_r: float | None = f(default=None, ge=0.0, le=4.0)
    nozzle_c: float | None = f(default=None, ge=0.0, le=500.0)
    bed_c: float | None = f(default=None, ge=0.0, le=200.0)


@schema("station.Check")
class Check:
    name: str
    ok: bool
    detail: str = ""


@schema("station.ReadyReport")
class ReadyReport:
    ready: bool
    checks: list[Check]


@schema("station.Calibration")
class CalibrationReport:
    correction_xyz_mm: list[float]
    correction_rpy_deg: list[float]
    residual_rms_mm: float
    points: int
    wobj_xyz_mm: list[float]
    wobj_rpy_deg: list[float]


@schema("station.MeshRequest")
class MeshRequest:
    """The as-printed part: a mesh (``stl``, ``glb``) or the bead list (``csv``: one row per bead in
    deposition order, ``x0_mm,y0_mm,z0_mm,x1_mm,y1_mm,z1_mm,volume_mm3``, plate frame)."""
    fmt: str = f(default="stl", choices=MESH_FORMATS)
