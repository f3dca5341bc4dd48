"""Messages of the pipeline services: slicer, planner, collision checker, supervisor."""
from __future__ import annotations

from typing import Any

import numpy as np

from fabric.schemas.base import f, schema
from fabric.schemas.common import ErrorReply
from fabric.wire.errors import COLD_EXTRUSION_REASONS, UNREACHABLE_REASONS

BACKENDS = ("builtin", "prusaslicer", "slic3r")
EXPORT_FORMATS = ("rapid", "krl", "urscript", "csv")
JOB_SOURCES = ("model", "gcode")
PRINT_JOB_STATES = ("queued", "slicing", "planning", "checking", "loaded", "printing", "paused",
                    "finished", "stopped", "failed", "interrupted")
FINAL_JOB_STATES = ("finished", "stopped", "failed")
ON_STATION_JOB_STATES = ("loaded", "printing", "paused", "interrupted")
WAITING_FOR = ("", "plate", "station", "queue")    # the operator's `job next`, a busy station, jobs ahead
MATERIAL_SOURCES = ("option", "gcode", "assumed")  # where a plan's filament diameter came from


# --- slicer ------------------------------------------------------------------

@schema("slicer.SliceRequest", version=2)
class SliceRequest:
    """Slice a model sent as bytes (so the slicer may run on another host), inline or uploaded in chunks."""
    model: bytes
    filename: str = f(max_len=255)
    profile: str = "taz-pla-medium"
    backend: str = f(default="builtin", choices=BACKENDS)
    overrides: dict[str, str] = f(factory=dict)
    center_xy_mm: list[float] | None = f(default=None, shape=(2,))
    upload_id: str = f(default="", max_len=64)      # a model sent in chunks to slicer/upload (``model`` is empty)


@schema("slicer.SliceResult")
class SliceResult:
    gcode_id: str
    backend: str
    layers: int
    extruded_mm3: float
    filament_mm: float
    model_volume_mm3: float
    faces: int
    elapsed_s: float
    warnings: list[str] = f(factory=list)


@schema("slicer.Backends")
class Backends:
    backends: dict[str, str]      # name -> version ("" when not installed)
    profiles: list[str]


# --- planner -----------------------------------------------------------------

@schema("planner.PlanRequest", version=3)
class PlanRequest:
    """Plan G-code given inline (``gcode``), uploaded in chunks (``upload_id``, planner/upload) or by the
    slicer's artifact id (``gcode_id``).

    ``filament_diameter_mm`` overrides what the G-code states (None: as stated, else assumed and said so)."""
    gcode: bytes = b""
    gcode_id: str = ""
    filename: str = "part.gcode"
    offset_mm: list[float] = f(factory=lambda: [0.0, 0.0, 0.0], shape=(3,))
    tilt_deg: list[float] = f(factory=lambda: [0.0, 0.0], shape=(2,))
    speed_r: float = f(default=1.0, ge=0.05, le=4.0)
    rot_step_deg: float = f(default=15.0, ge=0.5, le=90.0)
    wobj_xyz_mm: list[float] | None = f(default=None, shape=(3,))     # work object override (e.g. after calibration)
    wobj_rpy_deg: list[float] | None = f(default=None, shape=(3,))
    filament_diameter_mm: float | None = f(default=None, ge=0.5, le=5.0)
    allow_off_plate: bool = False               # targets off the plate or below it: counted, not fatal
    upload_id: str = f(default="", max_len=64)


@schema("planner.UnreachableTarget")
class UnreachableTarget:
    """The first target the robot cannot reach: where (G-code line, program row) and why."""
    gcode_line: int
    reason: str = f(choices=UNREACHABLE_REASONS)
    row: int = -1


@schema("planner.ColdExtrusion")
class ColdExtrusion:
    """The first move that would extrude below the material's minimum extrusion temperature ``min_c``:
    where (G-code line, program row), why, the nozzle's set point then (``nozzle_c``, set at
    ``set_line``, -1: never) and the temperature last waited for (``waited_c``, at ``wait_line``; None:
    nothing waited); ``message`` says it in a sentence (``fabric.motion.cold``)."""
    gcode_line: int
    reason: str = f(choices=COLD_EXTRUSION_REASONS)
    row: int = -1
    nozzle_c: float = 0.0
    min_c: float = 0.0
    set_line: int = -1
    waited_c: float | None = None
    wait_line: int = -1
    message: str = ""


@schema("planner.SlowedMove")
class SlowedMove:
    """The first linear move slowed down to keep a joint within its velocity limit."""
    gcode_line: int
    row: int
    joint: int = f(ge=1)        # the limiting axis, 1-based (A1 = 1)


@schema("planner.PlanSummary", version=4)
class PlanSummary:
    """What a plan produced. The material: ``filament_diameter_mm`` turned E into ``extruded_mm3``; it came
    from ``material_source`` (the request's option, the G-code's comments, or assumed: then ``warnings``
    says so); name, density and minimum extrusion temperature as the G-code states them (else empty).
    ``unreachable_by_reason`` counts targets by reason, "off the plate" and "below the plate" included.
    Not ``runnable``: a target is unreachable (``first_unreachable``) or a move would extrude below the
    material's minimum temperature (``cold_extrusion``)."""
    program_id: str
    targets: int
    moves: int
    layers: int
    feasible_r: float
    runnable: bool
    estimate_s: float
    extruded_mm3: float
    path_mm: float
    first_unreachable: UnreachableTarget | None = None
    unreachable_by_reason: dict[str, int] = f(factory=dict)
    elapsed_s: float = 0.0
    slowed_targets: int = 0                    # linear moves slowed to respect a joint velocity limit
    first_slowed: SlowedMove | None = None
    filament_diameter_mm: float = f(default=1.75, ge=0.5, le=5.0)
    material_source: str = f(default="assumed", choices=MATERIAL_SOURCES)
    material: str = ""
    density_g_cm3: float | None = None
    min_extrude_temp_c: float | None = None
    mass_g: float | None = None                # extruded_mm3 times the density, when the density is known
    warnings: list[str] = f(factory=list)
    allow_off_plate: bool = False              # targets off the plate or below it were allowed (still counted)
    cold_extrusion: ColdExtrusion | None = None


@schema("planner.ProgramMsg")
class ProgramMsg:
    """A whole robot program: its columns as packed arrays (see fabric.motion.program).

    Stored as a planner artifact whose id is the sha256 of this message's bytes."""
    columns: dict[str, np.ndarray]
    wobj: np.ndarray = f(dtype="<f8", shape=(4, 4), factory=lambda: np.eye(4))
    meta: dict[str, Any] = f(factory=dict)


@schema("planner.ExportRequest")
class ExportRequest:
    program_id: str
    fmt: str = f(choices=EXPORT_FORMATS)
    module_targets: int = f(default=5000, ge=10, le=1_000_000)


# --- collision ---------------------------------------------------------------

@schema("collision.CheckRequest")
class CollisionRequest:
    """Sweep a program (by id) or a single joint move (``q_from_deg`` -> ``q_to_deg``)."""
    program_id: str = ""
    q_from_deg: list[float] | None = None
    q_to_deg: list[float] | None = None
    step_deg: float = f(default=2.0, ge=0.1, le=30.0)
    include_part: bool = True


@schema("collision.Hit")
class CollisionHit:
    """The first colliding configuration of a sweep: when, where, and which two bodies touch."""
    body_a: str
    body_b: str
    t_s: float = -1.0                          # from the program start (-1: not timed, e.g. a single move)
    row: int = -1                              # program row (-1 for a single joint move)
    gcode_line: int = -1
    layer: int = -1
    move_r: float = f(default=0.0, ge=0.0, le=1.0)     # where along a single joint move (0 = start, 1 = end)


@schema("collision.Report", version=2)
class CollisionReport:
    collision_free: bool
    checked_configs: int
    min_distance_mm: float
    first_hit: CollisionHit | None = None
    elapsed_s: float = 0.0


# --- supervisor ---------------------------------------------------------------

@schema("supervisor.ServiceInfo", version=2)
class ServiceInfo:
    """One service of the cell: alive (its liveliness token), since when, and its own health."""
    name: str
    alive: bool
    since_s: float = 0.0
    health: str = f(default="", choices=("", "ok", "degraded"))   # "": not known (not alive, or did not answer)
    reasons: list[str] = f(factory=list)                  # why it is degraded (see common.Health)


@schema("supervisor.JobRecord", version=3)
class JobRecord:
    """One print job: what was submitted, where it is, what each stage produced, and how it ended.

    ``state`` goes queued -> slicing -> planning -> checking -> (queued, prepared) -> loaded ->
    printing <-> paused -> finished | stopped | failed | interrupted (see PRINT_JOB_STATES).
    Times ending in ``_s`` without "elapsed" are wall-clock epoch seconds (0 = not yet)."""
    job_id: str
    filename: str
    source: str = f(default="model", choices=JOB_SOURCES)      # a model to slice, or G-code to plan as it is
    profile: str = ""
    backend: str = ""
    model_id: str = ""                          # the submitted file (an artifact at the supervisor)
    overrides: dict[str, str] = f(factory=dict)  # slicing profile overrides
    start: bool = False                         # start printing once loaded
    rtf: float = f(default=1.0, ge=0.0, le=1e6)
    state: str = f(default="queued", choices=PRINT_JOB_STATES)
    prepared: bool = False                      # sliced, planned and checked: can be loaded
    waiting_for: str = f(default="", choices=WAITING_FOR)   # why a prepared job is not loaded yet ("": it will be)
    reason: str = ""                            # why it is in its state (a failure, an interruption, a stop)
    stage: str = ""                             # what it is doing now, in words
    progress_r: float = f(default=0.0, ge=0.0, le=1.0)
    layer: int = -1                             # the last layer begun (0-based), while printing
    created_s: float = 0.0
    updated_s: float = 0.0
    started_s: float = 0.0                      # the print began
    ended_s: float = 0.0                        # the print ended (finished, stopped, failed)
    sim_elapsed_s: float = 0.0                  # simulated duration of the print so far
    wall_elapsed_s: float = 0.0                 # wall-clock duration of the print so far
    filament_mm: float = 0.0                    # filament pushed by the print
    deposited_mm3: float = 0.0                  # volume deposited by the print
    gcode_id: str = ""                          # the slicer's G-code artifact, once sliced
    program_id: str = ""                        # the planner's program artifact, once planned
    plan: PlanSummary | None = None
    collisions: CollisionReport | None = None
    error: ErrorReply | None = None             # the typed error of a failed job


@schema("supervisor.JobMove")
class JobMove:
    """Put a waiting job at ``position`` of the queue (0 = next)."""
    job_id: str = f(max_len=128)
    position: int = f(default=0, ge=0, le=100000)


@schema("supervisor.Status", version=2)
class FabricStatus:
    cell: str
    services: list[ServiceInfo]
    job: JobRecord | None = None                # the latest job
    job_error: str = ""                         # why the latest job could not be read (then ``job`` is nil)


@schema("supervisor.JobSubmit", version=2)
class JobSubmit:
    """STL/OBJ/3MF bytes -> slice -> plan -> collision check -> load (-> start); or G-code bytes
    (``source`` "gcode") -> plan -> check -> load (-> start)."""
    model: bytes
    filename: str = f(max_len=255)
    source: str = f(default="model", choices=JOB_SOURCES)
    profile: str = "taz-pla-medium"
    backend: str = f(default="builtin", choices=BACKENDS)
    overrides: dict[str, str] = f(factory=dict)
    start: bool = False
    rtf: float = f(default=0.0, ge=0.0, le=1e6)


MAX_JOBS_PAGE = 10_000              # the most records one supervisor/jobs reply carries


@schema("supervisor.JobsQuery")
class JobsQuery:
    """A page of the print jobs in queue order (``common.Empty``, what older clients send, is the first page).

    ``limit`` jobs from the ``offset``-th (0-based), of ``states`` only when given."""
    offset: int = f(default=0, ge=0, le=1_000_000_000)
    limit: int = f(default=100, ge=0, le=MAX_JOBS_PAGE)
    states: list[str] = f(factory=list, choices=PRINT_JOB_STATES)


@schema("supervisor.JobList", version=4)
class JobList:
    """Print job records in queue order: a page of them (``supervisor/jobs``), or all (``job_move``)."""
    jobs: list[JobRecord]
    total: int = f(default=-1, ge=-1)          # jobs matching the query in all; -1: ``jobs`` holds every one
    offset: int = f(default=0, ge=0)           # the place of ``jobs[0]`` among them
