"""Messages of the pipeline services: slicer, planner, collision checker, supervisor."""
from __future__ import annotations

from typing import Any

import numpy as np

from fabric.schemas import states as st
from fabric.schemas.base import f, schema
from fabric.schemas.common import ErrorReply
from fabric.schemas.ids import FILE_ID_OR_NONE, UPLOAD_ID_OR_NONE
from fabric.schemas.station import CellInfo, RobotStatus
from fabric.schemas.upload import MAX_GCODE_BYTES, MAX_MODEL_BYTES, MAX_SUBMIT_BYTES
from fabric.wire.errors import COLD_EXTRUSION_REASONS, UNREACHABLE_REASONS, ValidationError

BACKENDS = ("builtin", "prusaslicer", "slic3r")
LAYER_MODES = ("planar", "curved")      # flat layers, or curved layers with a tilted nozzle (builtin only)
EXPORT_FORMATS = ("rapid", "krl", "urscript", "csv")
JOB_SOURCES = ("model", "gcode")
GCODE_SUFFIXES = (".gcode", ".gco", ".g", ".nc")   # a file named so is G-code (JobSubmit source "" infers it)
MODEL_SUFFIXES = (".stl", ".obj", ".3mf")          # a file named so is a model to slice
WAITING_FOR = ("", "plate", "station", "queue")    # the operator's `job next`, a busy station, jobs ahead
MATERIAL_SOURCES = ("option", "gcode", "assumed")  # where a plan's filament diameter came from


# --- slicer ------------------------------------------------------------------

@schema("slicer.SliceRequest", version=3)
class SliceRequest:
    """Slice a model sent as bytes (so the slicer may run on another host), inline or uploaded in chunks.

    Version 3: ``layers`` "curved" slices along curved layers (builtin back-end only) and writes the
    multi-axis G-code dialect (every move carries the nozzle axis as I J K)."""
    model: bytes = f(max_len=MAX_MODEL_BYTES)   # the model file's bytes (STL, OBJ or 3MF); empty when ``upload_id``
                                                # is given
    filename: str = f(max_len=255)  # its file name: the suffix (.stl, .obj, .3mf) says the format
    profile: str = "taz-pla-medium"     # the slicing profile (``slicer/backends`` lists them)
    backend: str = f(default="builtin", choices=BACKENDS)   # the slicer that slices it
    overrides: dict[str, str] = f(factory=dict)     # profile keys set for this slice, values as text
    center_xy_mm: list[float] | None = f(default=None, shape=(2,))  # where the part's center goes, plate frame
                                                                    # (nil: the plate's center)
    upload_id: str = f(default="", max_len=64, pattern=UPLOAD_ID_OR_NONE)   # a model sent in chunks to
                                                    # slicer/upload (``model`` is empty)
    layers: str = f(default="planar", choices=LAYER_MODES)   # planar, or curved (builtin only; multi-axis G-code)


@schema("slicer.SliceResult", version=3)
class SliceResult:
    """What slicing produced: the G-code (an artifact at the slicer) and its numbers."""
    gcode_id: str                   # the G-code's artifact id (``am/<cell>/slicer/artifact/<gcode_id>``)
    backend: str                    # the slicer that sliced it
    layers: int                     # layers in the G-code
    extruded_mm3: float             # volume the G-code extrudes
    filament_mm: float              # filament the G-code pushes
    model_volume_mm3: float         # the model's own volume
    faces: int                      # triangles of the model
    elapsed_s: float                # wall-clock time slicing took
    warnings: list[str] = f(factory=list)   # what the slicer warned about (may be empty)
    retractions: int = f(default=0, ge=0)   # retractions in the G-code (each one a stop of the nozzle)
    travel_mm: float = f(default=0.0, ge=0.0)    # XY length of the moves that do not extrude
    bridge_area_mm2: float = f(default=0.0, ge=0.0)  # area printed as bridges, summed over layers
    curved: dict[str, float] = f(factory=dict)  # curved layers: the slice's measured figures (version 3: overhang
                                                # against planar, thickness, tilt, neighbour angles, cusp)


@schema("slicer.Backends")
class Backends:
    """The slicing back-ends and profiles this slicer service offers."""
    backends: dict[str, str]      # name -> version ("" when not installed)
    profiles: list[str]           # profile names to give as ``profile``


# --- planner -----------------------------------------------------------------

@schema("planner.PlanRequest", version=5)
class PlanRequest:
    """Plan G-code given inline (``gcode``), uploaded in chunks (``upload_id``, planner/upload) or by the
    slicer's artifact id (``gcode_id``).

    ``filament_diameter_mm`` overrides what the G-code states (None: as stated, else assumed and said so).
    Version 4: ``max_turn_deg`` (G-code in the multi-axis dialect). Version 5: ``linear_tol_mm``."""
    gcode: bytes = f(default=b"", max_len=MAX_GCODE_BYTES)  # the G-code itself, inline (see Inputs: a large
                                    # file goes by upload)
    gcode_id: str = ""              # or the slicer's G-code artifact id
    filename: str = "part.gcode"    # a name for it (messages and the program's name)
    offset_mm: list[float] = f(factory=lambda: [0.0, 0.0, 0.0], shape=(3,))   # where the G-code origin goes,
                                    # plate frame: G-code point p becomes plate point p + offset_mm
    tilt_deg: list[float] = f(factory=lambda: [0.0, 0.0], shape=(2,))  # nozzle axis tilt about the plate's x,
                                    # then y axis (0, 0: vertical, pointing down)
    speed_r: float = f(default=1.0, ge=0.05, le=4.0)    # factor on every G-code feed rate
    rot_step_deg: float = f(default=15.0, ge=0.5, le=90.0)  # step of the search over the free rotation about
                                    # the nozzle axis (kept clear of joint limits and singularities)
    wobj_xyz_mm: list[float] | None = f(default=None, shape=(3,))     # work object override (e.g. after calibration):
                                    # the plate frame's origin in the robot base frame (nil: the cell's)
    wobj_rpy_deg: list[float] | None = f(default=None, shape=(3,))    # its roll, pitch, yaw (nil: the cell's)
    filament_diameter_mm: float | None = f(default=None, ge=0.5, le=5.0)   # nil: as the G-code states, else
                                    # 1.75 assumed (and said so in the summary's warnings)
    allow_off_plate: bool = False               # targets off the plate or below it: counted, not fatal
    upload_id: str = f(default="", max_len=64, pattern=UPLOAD_ID_OR_NONE)  # or G-code sent in chunks to
                                    # planner/upload
    max_turn_deg: float = f(default=5.0, ge=0.1, le=90.0)   # multi-axis G-code: a move turning the nozzle axis
                                    # more than this is planned as equal pieces
    linear_tol_mm: float = f(default=0.1, ge=0.01, le=10.0)  # a linear move whose joints, interpolated between
                                    # its two rows, would take the TCP further than this off its straight line is
                                    # planned in pieces on the line (the twin, the collision check and a
                                    # controller streamed the CSV's joints interpolate them)


@schema("planner.UnreachableTarget", version=3)
class UnreachableTarget:
    """The first target the robot cannot reach: where (G-code line, program row) and why (version 2:
    ``detail``, the why in words where there is more to say: which joint jumps, and by how much; version 3:
    the joint at fault as figures: ``joint`` (1-based, A1 = 1; 0: none), its angle there ``value_deg`` and,
    at a joint limit, the limit it passes ``limit_deg``: "joint limit: A5 at 123.0 deg, past its limit 115
    deg"; a joint jump through the wrist singularity says so)."""
    gcode_line: int                 # the G-code line (1-based; -1: not from G-code)
    reason: str = f(choices=UNREACHABLE_REASONS)    # why
    row: int = -1                   # the program row
    detail: str = ""                # more on why, in words ("" when the reason says it all)
    joint: int = f(default=0, ge=0)         # the joint at fault, 1-based (A1 = 1; 0: none)
    value_deg: float | None = None          # its angle at the target (nil: no joint at fault)
    limit_deg: float | None = None          # the limit it passes (nil: not a joint limit)

    def why(self) -> str:
        """The reason, and its detail when there is one."""
        return f"{self.reason}: {self.detail}" if self.detail else self.reason

    def error_details(self) -> dict[str, Any]:
        """The details of the ``unreachable`` error that reports this target (``UnreachableError(msg, **...)``):
        where, why, and the joint at fault with its angle and limit where there is one (``joint`` 0-based there,
        as in every unreachable error's details: A5 is 4)."""
        out: dict[str, Any] = {"gcode_line": self.gcode_line, "reason": self.reason, "row": self.row}
        if self.detail:
            out["detail"] = self.detail
        if self.joint:
            out.update(joint=self.joint - 1, value_deg=self.value_deg)
        if self.limit_deg is not None:
            out["limit_deg"] = self.limit_deg
        return out


@schema("planner.ColdExtrusion")
class ColdExtrusion:
    """The first move that would extrude below the material's minimum extrusion temperature ``min_c``:
    where (G-code line, program row), why, the nozzle's set point then (``nozzle_c``, set at
    ``set_line``, -1: never) and the temperature last waited for (``waited_c``, at ``wait_line``; None:
    nothing waited); ``message`` says it in a sentence (``fabric.motion.cold``)."""
    gcode_line: int                 # the G-code line of the move (1-based)
    reason: str = f(choices=COLD_EXTRUSION_REASONS)     # why it would be cold
    row: int = -1                   # the program row of the move
    nozzle_c: float = 0.0           # the nozzle's set point then
    min_c: float = 0.0              # the material's minimum extrusion temperature
    set_line: int = -1              # the G-code line that set ``nozzle_c`` (-1: never set)
    waited_c: float | None = None   # the temperature last waited for (nil: nothing waited)
    wait_line: int = -1             # the G-code line of that wait (-1: none)
    message: str = ""               # the finding in a sentence


@schema("planner.SlowedMove")
class SlowedMove:
    """The first linear move slowed down to keep a joint within its velocity limit."""
    gcode_line: int             # the G-code line of the move (1-based)
    row: int                    # its program row
    joint: int = f(ge=1)        # the limiting axis, 1-based (A1 = 1)


@schema("planner.PlanSummary", version=6)
class PlanSummary:
    """What a plan produced. The material: ``filament_diameter_mm`` turned E into ``extruded_mm3``; it came
    from ``material_source`` (the request's option, the G-code's comments, or assumed: then ``warnings``
    says so); name, density and minimum extrusion temperature as the G-code states them (else empty).
    ``unreachable_by_reason`` counts targets by reason, "off the plate" and "below the plate" included;
    ``unreachable_by_joint`` (version 6) the joint-limit and joint-jump targets by the joint at fault.
    Not ``runnable``: a target is unreachable (``first_unreachable``) or a move would extrude below the
    material's minimum temperature (``cold_extrusion``)."""
    program_id: str                            # the program's artifact id (``am/<cell>/planner/artifact/<id>``)
    targets: int                               # motion rows of the program (joint and linear moves)
    moves: int                                 # moves read from the G-code
    layers: int                                # layers of the G-code
    feasible_r: float                          # share of motion rows the robot can reach
    runnable: bool                             # the station may run it (see above)
    estimate_s: float                          # the program's duration at real time (simulated seconds)
    extruded_mm3: float                        # volume the program deposits
    path_mm: float                             # TCP path length of the print section's linear moves
    first_unreachable: UnreachableTarget | None = None     # the first unreachable target (nil: none)
    unreachable_by_reason: dict[str, int] = f(factory=dict)    # unreachable targets counted by reason
    unreachable_by_joint: dict[str, int] = f(factory=dict)     # joint-limit and joint-jump targets by the joint
                                               # at fault ("A5": the joint furthest past its limit, or that turns most)
    elapsed_s: float = 0.0                     # wall-clock time planning took
    slowed_targets: int = 0                    # linear moves slowed to respect a joint velocity limit
    first_slowed: SlowedMove | None = None     # the first of them (nil: none)
    filament_diameter_mm: float = f(default=1.75, ge=0.5, le=5.0)  # the diameter that turned E into volume
    material_source: str = f(default="assumed", choices=MATERIAL_SOURCES)  # where that diameter came from
    material: str = ""                         # the material's name as the G-code states it ("" when it does not)
    density_g_cm3: float | None = None         # as the G-code states it (nil: not stated)
    min_extrude_temp_c: float | None = None    # as the G-code states it (nil: not stated)
    mass_g: float | None = None                # extruded_mm3 times the density, when the density is known
    warnings: list[str] = f(factory=list)      # what the planner warns about (an assumed diameter, ...)
    allow_off_plate: bool = False              # targets off the plate or below it were allowed (still counted)
    cold_extrusion: ColdExtrusion | None = None    # the first move that would extrude cold (nil: none)
    native_export: str = ""                    # the export the cell's controller runs (rapid, krl, urscript; csv
                                               # for a cell of no brand): another brand's is a text, not a program

    def counted(self) -> str:
        """" (338 targets at joint limit: A5 338)": the targets the robot cannot reach, by reason and by the joint
        at fault ("" when it reaches every one)."""
        counts = {k: v for k, v in self.unreachable_by_reason.items() if k in UNREACHABLE_REASONS and k != "singular"}
        if not counts:
            return ""
        text = ", ".join(f"{n} targets {'at ' if reason.startswith('joint') else ''}{reason}"
                         for reason, n in counts.items())
        if self.unreachable_by_joint:
            text += ": " + ", ".join(f"{joint} {n}" for joint, n in self.unreachable_by_joint.items())
        return f" ({text})"


@schema("planner.ProgramMsg")
class ProgramMsg:
    """A whole robot program: its columns as packed arrays, one row per instruction (``fabric.motion.program``).

    Stored as a planner artifact (media type ``application/x-am-fabric-program+msgpack``) whose id is the
    sha256 of this message's bytes. Every column has one row per instruction (n rows): ``op`` (u1:
    0 MoveJ, 1 MoveL, 2 Wait, 3 SetTemp, 4 WaitTemp, 5 Retract), ``section`` (u1: 0 approach, 1 print,
    2 return home), ``q_rad`` (f8, n x nq: joint targets, nq the arm's joints), ``xyz_mm`` (f8, n x 3)
    and ``quat_wxyz`` (f8, n x 4): the TCP target in the plate frame, ``speed_mm_s`` (f8: MoveL TCP speed),
    ``vel_r`` (f8: MoveJ share of the joints' velocity limits), ``zone_mm`` (f8: blending zone, 0 = stop point),
    ``flow_mm3_mm`` (f8: volume deposited per mm of path, 0 = extruder off), ``value`` (f8: Wait seconds,
    SetTemp/WaitTemp Celsius, Retract filament mm, negative = retract), ``aux`` (i2: heater of
    SetTemp/WaitTemp, 0 nozzle, 1 bed), ``gcode_line`` (i8: source line, -1 none) and ``layer`` (i4:
    0-based, -1 outside the print). Non-motion rows repeat the previous row's joints and TCP."""
    columns: dict[str, np.ndarray]     # column name -> packed array (see above)
    wobj: np.ndarray = f(dtype="<f8", shape=(4, 4), factory=lambda: np.eye(4))    # the work object the joints
                                       # were solved for: the plate frame in the robot base frame, 4x4, mm
    meta: dict[str, Any] = f(factory=dict)     # free-form facts of the plan (options, material, source lines):
                                               # informative, not part of the contract


@schema("planner.ExportRequest")
class ExportRequest:
    """A planned program in a robot language or as CSV, whole in one reply (``export_chunk`` streams it)."""
    program_id: str                 # the planned program (an artifact id of the planner)
    fmt: str = f(choices=EXPORT_FORMATS)    # rapid (ABB), krl (KUKA), urscript (Universal Robots) or csv
    module_targets: int = f(default=5000, ge=10, le=1_000_000)  # targets per module of the robot language


# --- collision ---------------------------------------------------------------

COLLISION_BEADS = ("none", "station")             # a single move: no part, or the part the twin has laid
MOVE_KINDS = ("print", "travel", "approach", "retract", "home", "joint", "recover", "restart", "descent",
              "jog", "deposit")
MAX_BEADS_PAGE = 65536                            # beads per station/beads reply (about 4.5 MB)


@schema("collision.CheckRequest", version=4)
class CollisionRequest:
    """Certify a program (by id) or a single joint move (``q_from_deg`` -> ``q_to_deg``), with the straight
    descent that follows it when a print restarts at a layer (``q_down_deg``, version 3): every robot body,
    the tool and the nozzle against the table, the plate, the part as printed and the robot itself, with
    nothing missed between checked configurations (see fabric.collision.certify). Version 4: ``from_row``,
    the rest of a program on the part on the plate (a restart at a layer, a recovery): its moves from that
    row to the return home against the station's beads (``beads`` "station") and those it lays itself, and
    none of its beads laid into the part (a hit of kind ``deposit``)."""
    program_id: str = ""                # the planner's program to sweep ("" for a single move)
    q_from_deg: list[float] | None = None   # a single move's start joints
    q_to_deg: list[float] | None = None     # and its end joints
    step_deg: float = f(default=2.0, ge=0.1, le=30.0)   # version 1's sampling step: accepted, no longer used
    include_part: bool = True           # a program: its own beads, each an obstacle once it is laid
    beads: str = f(default="none", choices=COLLISION_BEADS)   # a single move: "station" takes the beads the
                                        # twin has actually laid (asked from station/beads, kept between checks)
    tip_layer: int = f(default=-2, ge=-2)   # a single move: the layer whose beads (and those it rests on) the
                                        # nozzle tip may touch; -1 none, -2 the layer of the last bead laid
    vel_r: float = f(default=0.5, ge=0.001, le=1.0)   # a single move: share of the joint speed limits (the
                                        # twin's joint move, whose path depends on it)
    kind: str = f(default="joint", choices=MOVE_KINDS)   # a single move: what it is, for the report
    q_start_deg: list[float] | None = None  # a program: the joints it starts from (nil: the cell's home)
    tolerance_mm: float = f(default=0.01, ge=0.001, le=1.0)   # bodies this close count as touching
    q_down_deg: list[float] | None = None   # a single move: after it, straight down from ``q_to_deg`` to these
                                        # joints (a linear move, joints interpolated as the twin does; kind
                                        # "descent" in a hit): a restart's way onto the part (nil: none)
    down_layer: int = f(default=-1, ge=-1)  # the layer that descent goes on printing: the nozzle tip may touch
                                        # its beads and those of the layers it rests on, as when printing it (-1: none)
    from_row: int = f(default=-1, ge=-1)    # a program: only its rows from this one on, starting at
                                        # ``q_start_deg``, on the beads ``beads`` names, and none of the beads
                                        # of the rows after it into them (that row may be one cut short, its
                                        # bead laid in part: it goes on along it) (-1: the whole program
                                        # from the cell's home, on an empty plate)


@schema("collision.Hit", version=2)
class CollisionHit:
    """The first contact of a sweep: which two bodies, on which move, where and when."""
    body_a: str                                # the robot body (a link, tool_body, tool_nozzle, tool_tip)
    body_b: str                                # what it touches: table, plate, part (a bead) or a robot body
    t_s: float = -1.0                          # program time from its start, simulated (-1: not timed, e.g. a move)
    row: int = -1                              # program row (-1 for a single joint move)
    gcode_line: int = -1                       # the G-code line of that row (-1: none)
    layer: int = -1                            # the layer of that row (0-based; -1: none)
    move_r: float = f(default=0.0, ge=0.0, le=1.0)     # where along the move (0 = start, 1 = end)
    kind: str = f(default="", choices=("",) + MOVE_KINDS)   # the move: print, travel, approach, retract, home,
                                               # joint (a program's joint move, or a station move), recover,
                                               # restart, descent (a restart's straight way down onto the part),
                                               # jog (an operator's straight move by hand), deposit (a bead the
                                               # program would lay into the part on the plate: body_a "bead")
    xyz_mm: list[float] | None = f(default=None, shape=(3,))   # the nozzle tip there (plate frame)
    distance_mm: float = 0.0                   # the distance found there (<= the tolerance; < 0: overlapping)
    bead: int = -1                             # the bead touched, in print order (-1: not a bead)
    bead_layer: int = -1                       # its layer
    bead_gcode_line: int = -1                  # the G-code line that laid it (-1: not known)
    message: str = ""                          # all of the above in one line, for people


@schema("collision.Report", version=3)
class CollisionReport:
    """The verdict of a certified sweep: collision free with the certified clearance, or the first hit."""
    collision_free: bool               # no contact anywhere along the motion
    checked_configs: int               # configurations at which exact distances were computed
    min_distance_mm: float             # the certified clearance: a lower bound of the distance between bodies
                                       # that may not touch, all along the motion (-1: nothing moved)
    first_hit: CollisionHit | None = None  # the first contact along the motion (nil: none)
    elapsed_s: float = 0.0             # wall-clock time the sweep took
    clearance_body: str = ""           # where the clearance is smallest: the body (or the pair of bodies)
    clearance_gcode_line: int = -1     # and the G-code line (-1: none)
    clearance_layer: int = -1          # and the layer (-1: none)
    segments: int = 0                  # path segments certified (joint-space pieces between targets)
    swept_pieces: int = 0              # pieces of linear moves checked as swept hulls of the nozzle and the tool
    beads: int = 0                     # bead solids in the part (laid by the program, or by the twin)
    exemption: str = ""                # the only contact not checked: the nozzle tip on its own layer and
                                       # those it rests on (size in words)
    tolerance_mm: float = 0.01         # bodies this close count as touching


@schema("collision.BeadsQuery")
class BeadsQuery:
    """A page of the beads the twin has laid (station/beads), in deposition order."""
    first: int = f(default=0, ge=0)                                # the first bead wanted
    limit: int = f(default=MAX_BEADS_PAGE, ge=1, le=MAX_BEADS_PAGE)   # at most this many


@schema("collision.Beads")
class Beads:
    """Beads ``first`` .. ``first + n - 1`` of the part on the plate, in the plate frame of the program that
    laid them (``wobj``); ``part_id`` changes when another part starts (a new print, a plate cleared, a
    station restarted), so a cache of earlier pages knows when to start over."""
    part_id: str                                                  # names the part these beads make up
    total: int                                                    # beads laid so far
    first: int                                                    # the index of the first bead here
    start_mm: np.ndarray = f(dtype="<f8", shape=(None, 3), factory=lambda: np.zeros((0, 3)))   # nozzle path
    end_mm: np.ndarray = f(dtype="<f8", shape=(None, 3), factory=lambda: np.zeros((0, 3)))     # start to end
    width_mm: np.ndarray = f(dtype="<f8", shape=(None,), factory=lambda: np.zeros(0))        # bead width
    height_mm: np.ndarray = f(dtype="<f8", shape=(None,), factory=lambda: np.zeros(0))       # and height
    layer: np.ndarray = f(dtype="<i8", shape=(None,), factory=lambda: np.zeros(0, np.int64))   # 0-based
    row: np.ndarray = f(dtype="<i8", shape=(None,), factory=lambda: np.zeros(0, np.int64))     # program row
    gcode_line: np.ndarray = f(dtype="<i8", shape=(None,), factory=lambda: np.zeros(0, np.int64))   # -1: none
    wobj: np.ndarray = f(dtype="<f8", shape=(4, 4), factory=lambda: np.eye(4))    # plate frame in the robot
                                                                  # base frame (mm)
    axis: np.ndarray = f(dtype="<f8", shape=(None, 3), factory=lambda: np.zeros((0, 3)))   # nozzle axis each
                                                                  # bead was laid with (plate frame, tip up);
                                                                  # empty: straight up (planar printing)


# --- supervisor ---------------------------------------------------------------

@schema("supervisor.ServiceInfo", version=2)
class ServiceInfo:
    """One service of the cell: alive (its liveliness token), since when, and its own health."""
    name: str                                             # the service
    alive: bool                                           # it holds its liveliness token
    since_s: float = 0.0                                  # alive since (wall clock, epoch seconds; 0: not alive)
    health: str = f(default="", choices=("", "ok", "degraded"))   # "": not known (not alive, or did not answer)
    reasons: list[str] = f(factory=list)                  # why it is degraded (see common.Health)


SEGMENT_BEGINNINGS = ("start", "restart", "recover")    # from the beginning, at a layer, after an interruption
SEGMENT_ENDS = ("", "finished", "stopped", "failed", "interrupted")   # "": it is running


@schema("supervisor.JobSegment")
class JobSegment:
    """One run of a job's program on the station, from how it began (``start`` from the beginning,
    ``restart`` at a layer after a stop or a finished print, ``recover`` after an interruption) to how it
    ended ("" while it runs). Wall-clock times; ``sim_s`` on the station's clock (pauses included);
    ``deposited_mm3`` what this run deposited."""
    began: str = f(default="start", choices=SEGMENT_BEGINNINGS)    # how it began (see above)
    from_layer: int = 0                         # the layer it began at (0-based)
    started_s: float = 0.0                      # it began (wall clock)
    ended_s: float = 0.0                        # it ended (wall clock; 0 while it runs)
    ended: str = f(default="", choices=SEGMENT_ENDS)   # how it ended ("" while it runs)
    reason: str = ""                            # why it ended so (a stop, a fault, an interruption)
    t_sim_start_s: float = 0.0                  # the station's clock when it began
    sim_s: float = 0.0                          # simulated time it has run
    deposited_mm3: float = 0.0                  # volume it deposited
    pauses: int = 0                             # times it was paused
    last_layer: int = -1                        # the last layer it began (0-based)


@schema("supervisor.JobOverride")
class JobOverride:
    """A live override the operator set while the job was on the station: when, at which layer, what."""
    wall_s: float                               # when (wall clock)
    t_sim_s: float = 0.0                        # when (the station's clock)
    layer: int = -1                             # the layer being printed then (0-based)
    speed_r: float | None = None                # speed factor set (nil: not changed)
    flow_r: float | None = None                 # flow factor set (nil: not changed)
    nozzle_c: float | None = None               # nozzle set point set (nil: not changed)
    bed_c: float | None = None                  # bed set point set (nil: not changed)


@schema("supervisor.JobRecord", version=5)
class JobRecord:
    """One print job: what was submitted, where it is, what each stage produced, and how it ended.

    ``state`` goes queued -> slicing -> planning -> checking -> (queued, prepared) -> loaded ->
    printing <-> paused -> finished | stopped | failed | interrupted (each state's meaning: "Print job
    states" in the protocol reference).
    Times ending in ``_s`` without "elapsed" are wall-clock epoch seconds (0 = not yet).
    ``segments`` are the runs of its print (a stop and a restart at a layer, an interruption and its
    recovery: each a segment); ``started_s`` is the first one's start, the durations and the material are
    their totals. ``live_overrides`` are the speed, flow and temperature overrides set while it printed
    (they end with the job). Version 4: ``segments`` and ``live_overrides``. Version 5: ``layers``."""
    job_id: str                                 # the job's id (12 hex digits)
    filename: str                               # the submitted file's name
    source: str = f(default="model", choices=JOB_SOURCES)      # a model to slice, or G-code to plan as it is
    profile: str = ""                           # the slicing profile (a model)
    backend: str = ""                           # the slicer (a model)
    model_id: str = ""                          # the submitted file (an artifact at the supervisor)
    overrides: dict[str, str] = f(factory=dict)  # slicing profile overrides
    layers: str = f(default="planar", choices=LAYER_MODES)     # planar or curved layers (a model; version 5)
    start: bool = False                         # start printing once loaded (as submitted; job next keeps it)
    rtf: float = f(default=1.0, ge=0.0, le=1e6)     # the real-time factor its print runs at
    state: st.PrintJob = f(default=st.PrintJob.QUEUED)     # see "Print jobs" in docs/protocol.md
    prepared: bool = False                      # sliced, planned and checked: can be loaded
    waiting_for: str = f(default="", choices=WAITING_FOR)   # why a prepared job is not loaded yet ("": it will be)
    reason: str = ""                            # why it is in its state (a failure, an interruption, a stop)
    stage: str = ""                             # what it is doing now, in words
    progress_r: float = f(default=0.0, ge=0.0, le=1.0)     # share of the stage (preparing) or of the print done
    layer: int = -1                             # the last layer begun (0-based), while printing
    created_s: float = 0.0                      # submitted (wall clock, epoch seconds)
    updated_s: float = 0.0                      # the record last changed (wall clock, epoch seconds)
    started_s: float = 0.0                      # the print began (wall clock, epoch seconds; 0: not yet)
    ended_s: float = 0.0                        # the print ended: finished, stopped, failed (wall clock, epoch
                                                # seconds; 0: not yet)
    sim_elapsed_s: float = 0.0                  # simulated duration of the print so far
    wall_elapsed_s: float = 0.0                 # wall-clock duration of the print so far
    filament_mm: float = 0.0                    # filament pushed by the print
    deposited_mm3: float = 0.0                  # volume deposited by the print
    gcode_id: str = ""                          # the slicer's G-code artifact, once sliced
    program_id: str = ""                        # the planner's program artifact, once planned
    plan: PlanSummary | None = None             # the plan's summary, once planned
    collisions: CollisionReport | None = None   # the collision check's report, once checked
    error: ErrorReply | None = None             # the typed error of a failed job
    segments: list[JobSegment] = f(factory=list)        # every run of the print, in order
    filament_diameter_mm: float | None = f(default=None, ge=0.5, le=5.0)  # as submitted (nil: the G-code's)
    live_overrides: list[JobOverride] = f(factory=list)  # overrides set while it was on the station


@schema("supervisor.JobMove")
class JobMove:
    """Put a waiting job at ``position`` of the queue (0 = next)."""
    job_id: str = f(max_len=128)                # the job to move (one still waiting: queued or preparing)
    position: int = f(default=0, ge=0, le=100000)   # its place among the waiting jobs (0 = next)


@schema("supervisor.Status", version=4)
class FabricStatus:
    """The cell at a glance: every service (alive, healthy) and the current job."""
    cell: str                                   # the cell's name
    services: list[ServiceInfo]                 # every service of the cell, alive or not
    job: JobRecord | None = None                # the job on the station, else the latest job (nil: none)
    job_error: str = ""                         # why the latest job could not be read (then ``job`` is nil)
    station_cell: CellInfo | None = None        # the cell model the station runs (nil: no station answered)
    robot: RobotStatus | None = None            # the robot the station drives (nil: the twin alone, or no station)


@schema("supervisor.JobSubmit", version=7)
class JobSubmit:
    """STL/OBJ/3MF bytes -> slice -> plan -> collision check -> load (-> start); or G-code bytes
    (``source`` "gcode") -> plan -> check -> load (-> start). The file enters the supervisor's library
    (``supervisor/files``). It comes in one of three ways: inline (``model``), uploaded in chunks to
    ``supervisor/upload`` (``upload_id``, ``model`` empty; version 7), or from the library (``file_id``,
    ``model`` empty: prints a library file again; version 5).

    ``source`` empty (the default) is taken from ``filename``: .gcode, .gco, .g and .nc are G-code; .stl,
    .obj and .3mf a model; any other name is a ``validation`` error naming ``source``. The print runs at
    real time (``rtf`` 1) unless asked otherwise, as ``fabric-cli job submit`` does. Version 3: ``source``
    defaults to "" (inferred) and ``rtf`` to 1 (it was "model" and 0, as fast as possible). Version 6:
    ``layers`` "curved" slices a model along curved layers with a tilted nozzle (built-in slicer; the
    multi-axis G-code dialect, planned with the nozzle axis of every move). Version 7: ``upload_id``."""
    model: bytes = f(max_len=MAX_SUBMIT_BYTES)     # the file's bytes (a model, or G-code; a model:
                                                # at most what the slicer takes, see Inputs); empty with
                                                # ``upload_id`` or ``file_id``
    filename: str = f(max_len=255)              # its name (its suffix gives ``source`` when that is empty;
                                                # "" with ``file_id``: the library's name)
    source: str = f(default="", choices=("", *JOB_SOURCES))    # model, gcode, or "": from the file name
    profile: str = "taz-pla-medium"             # the slicing profile (a model)
    backend: str = f(default="builtin", choices=BACKENDS)      # the slicer (a model)
    overrides: dict[str, str] = f(factory=dict)     # slicing profile keys set for this job, values as text
    start: bool = False                         # start printing as soon as it is loaded (else: fabric-cli start)
    rtf: float = f(default=1.0, ge=0.0, le=1e6)     # real-time factor of the print: 1 = real time, 0 = as fast
                                                # as possible
    filament_diameter_mm: float | None = f(default=None, ge=0.5, le=5.0)   # the filament the print uses, for
                                                # G-code that does not say it (nil: as stated, else assumed);
                                                # a model is sliced for it (version 4)
    file_id: str = f(default="", max_len=64, pattern=FILE_ID_OR_NONE)   # a library entry to print (``model``
                                                # empty; its id or a start of it), version 5
    layers: str = f(default="planar", choices=LAYER_MODES)     # planar, or curved (a model, builtin slicer;
                                                # version 6)
    upload_id: str = f(default="", max_len=64, pattern=UPLOAD_ID_OR_NONE)  # a file sent in chunks to
                                                # supervisor/upload (``model`` empty), version 7


def source_of(filename: str, source: str = "") -> str:
    """A submitted file's source: ``source`` when given, else what the file name says (``GCODE_SUFFIXES``:
    gcode, ``MODEL_SUFFIXES``: model); a name that says neither is a ValidationError naming ``source``."""
    if source:
        return source
    suffix = "." + filename.rsplit(".", 1)[-1].lower() if "." in filename else ""
    if suffix in GCODE_SUFFIXES:
        return "gcode"
    if suffix in MODEL_SUFFIXES:
        return "model"
    raise ValidationError(f"cannot tell from the file name {filename!r} whether it is a model or G-code: name it "
                          f"{', '.join(MODEL_SUFFIXES)} or {', '.join(GCODE_SUFFIXES)}, or give source "
                          f"({' or '.join(JOB_SOURCES)})", field="source", filename=filename)


MAX_JOBS_PAGE = 10_000              # the most records one supervisor/jobs reply carries
QUEUE_CHANGES = ("submitted", "removed", "moved")


@schema("supervisor.QueueChange")
class QueueChange:
    """The print-job queue changed, published on ``supervisor/queue`` once the change is on disk: a job was
    submitted, removed (the supervisor keeps no record of it any more: ``job`` finds it no more, and no
    ``jobs`` record announces it) or moved. A console or monitor keeps its list by it without asking again;
    ``waiting`` is then the whole waiting queue in order."""
    kind: str = f(choices=QUEUE_CHANGES)     # submitted, removed or moved
    job_id: str                              # the job submitted, removed or moved
    waiting: list[str] = f(factory=list)     # the waiting jobs' ids (queued, slicing, planning, checking), in
                                             # queue order, after the change


@schema("supervisor.JobsQuery")
class JobsQuery:
    """A page of the print jobs in queue order (``common.Empty``, what older clients send, is the first page).

    ``limit`` jobs from the ``offset``-th (0-based), of ``states`` only when given."""
    offset: int = f(default=0, ge=0, le=1_000_000_000)      # skip this many matching jobs
    limit: int = f(default=100, ge=0, le=MAX_JOBS_PAGE)     # the most jobs in the reply
    states: list[st.PrintJob] = f(factory=list)  # only jobs in these states (empty: all)


@schema("supervisor.JobList", version=4)
class JobList:
    """Print job records in queue order: the page asked (``supervisor/jobs``), or the first page after a
    ``job_move`` (up to 100 records, with ``total``)."""
    jobs: list[JobRecord]                      # the records in queue order: as submitted, as reordered by job_move
    total: int = f(default=-1, ge=-1)          # jobs matching the query in all (-1, from older services:
                                               # ``jobs`` holds every one)
    offset: int = f(default=0, ge=0)           # the place of ``jobs[0]`` among them
