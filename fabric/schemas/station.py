"""Station (digital twin) messages: telemetry, commands and reports.

Small fixed vectors (a pose's 3 coordinates, the arm's joints) are plain lists so a
monitor needs nothing but msgpack; bulk data elsewhere is packed arrays.
"""
from __future__ import annotations

from typing import Any

from fabric.schemas import states
from fabric.schemas.base import f, schema
from fabric.schemas.states import STATION_STATES

MESH_FORMATS = ("stl", "glb", "csv")
STATES = STATION_STATES


@schema("station.Pose")
class Pose:
    """TCP pose (plate frame and robot base frame) and joints of the twin.

    The plate frame is the work object: origin at the plate's top-face corner (x min, y min), z up
    from its surface, as calibrated (``station.State`` ``wobj_xyz_mm``/``wobj_rpy_deg`` place it in the
    robot base frame)."""
    seq: int                     # the pose stream's sample number: from 1 for each run of the station process,
                                 # +1 per published sample (a ``position`` reply: that of the last sample)
    t_sim_s: float               # the station's simulated clock when sampled
    q_deg: list[float]           # joint angles A1..An (the arm's joints: 6, or 7 for the Panda cell), degrees
    xyz_mm: list[float]          # TCP in the plate frame (work object), x y z
    quat_wxyz: list[float]       # TCP orientation in the plate frame: unit quaternion w x y z
    base_xyz_mm: list[float]     # TCP in the robot base frame, x y z
    wall_time_s: float = 0.0     # wall clock when sampled (epoch seconds)


@schema("station.Extrusion")
class Extrusion:
    """The extruder now: on or off, its flow, and what the print has pushed so far."""
    seq: int                     # this stream's own number: from 1 for each run of the station process, no gaps
    t_sim_s: float               # the station's simulated clock
    on: bool                     # the extruder is pushing filament
    flow_mm3_s: float            # volume flow now (0 when off)
    extruded_mm3: float          # volume deposited by the current print since it started
    filament_mm: float           # filament pushed by the current print (retractions counted)
    layer: int                   # layer being printed (0-based; -1 before the first)
    row: int                     # program row being executed
    gcode_line: int              # the G-code line that row came from (1-based; -1: none)
    flow_r: float = 1.0          # the flow override (1 = as programmed)


@schema("station.Temps")
class Temps:
    """Heater temperatures now and their set points."""
    nozzle_c: float              # nozzle temperature now
    nozzle_target_c: float       # nozzle set point (0 = heater off)
    bed_c: float                 # bed temperature now
    bed_target_c: float          # bed set point (0 = heater off)
    t_sim_s: float = 0.0         # the station's simulated clock


@schema("station.Robot")
class RobotStatus:
    """The robot controller the station drives (``fabric-cli up --robot franka:HOST``): absent for the twin
    alone. The twin is then the robot's shadow: pose telemetry is the measured joints'."""
    address: str                       # the controller, KIND:HOST ("franka:172.16.0.2")
    connected: bool                    # the connection is open
    following: bool = False            # the station streams its commanded path to it
    mode: str = ""                     # the controller's own mode ("Idle", "Move", "Reflex", ...)
    server_version: int = 0            # the controller's server version (0: not known yet)
    errors: list[str] = f(factory=list)    # the controller's active errors, by its names
    fault: str = ""                    # why driving it stopped (a reflex, the connection lost), or why connecting
                                       # failed, in one line ("" when none)
    deviation_mm: float = 0.0          # the commanded-versus-measured TCP deviation at the last control step
    deviation_max_mm: float = 0.0      # the largest while laying beads in the current run (reset when one starts)
    bound_mm: float = 0.5              # a print pauses when the deviation exceeds this (the cell's bound)

    def line(self) -> str:
        """The robot in one line (``fabric-cli status``, the console's banner)."""
        if not self.connected:
            return f"robot {self.address}: NOT CONNECTED: {self.fault or 'not yet'} (recover connects again)"
        said = [f"mode {self.mode}" if self.mode else "",
                f"server version {self.server_version}" if self.server_version else "",
                "following the twin" if self.following else "NOT FOLLOWING",
                f"off its path {self.deviation_mm:.2f} mm (beads at most {self.deviation_max_mm:.2f} of "
                f"{self.bound_mm:g})"]
        errors = f"; ERRORS: {', '.join(self.errors)}" if self.errors else ""
        fault = f"; FAULT: {self.fault}" if self.fault else ""
        return f"robot {self.address}: connected, " + ", ".join(x for x in said if x) + errors + fault

    @property
    def ok(self) -> bool:
        """Connected, following, no error, no fault."""
        return self.connected and self.following and not self.errors and not self.fault


@schema("station.Deviation")
class Deviation:
    """The commanded-versus-measured TCP deviation of a robot the station drives, per pose sample: the control
    steps since the last sample (any motion), and the current run's figures over the steps that laid a bead
    (reset when a motion starts from rest)."""
    seq: int                     # this stream's number: from 1 for each run of the station process
    t_sim_s: float               # the station's simulated clock (the commanded path's time)
    now_mm: float                # the last control step's deviation
    tick_max_mm: float           # the largest since the last sample
    p50_mm: float                # the run's median
    p99_mm: float                # the run's 99th percentile
    max_mm: float                # the run's largest
    steps: int                   # control steps of the run counted
    row: int = -1                # the program row then (-1: none)
    gcode_line: int = -1         # its G-code line (-1: none)
    bound_mm: float = 0.5        # the cell's bound: a print pauses past it


@schema("station.State", version=4)
class StationState:
    """The station's whole state: a snapshot reply and a publication on change.

    ``t_sim_s`` is the station's simulated clock (the same clock as pose, extrusion and events);
    ``elapsed_s`` the job's simulated time since it started. ``layer`` is the 0-based index of the
    layer being printed, as in events (people read ``layer + 1`` of ``layers_total``).
    ``progress_r`` is where the print is in its program: the planned volume of the rows done over the
    program's, whatever a flow override deposits (0 while heating, frozen while paused, where it stopped
    for a stopped print, 1 when finished). ``plate_clear`` is false from the first
    bead of a print until the operator says the part is off the plate (``clear_plate``); ``plate_mm3``
    and ``plate_job_id`` say what is on it."""
    state: states.Station                # see "Station states" in docs/protocol.md
    reason: str = ""                   # why it is in that state, in words (``finished`` after a finished print)
    program_id: str = ""               # the program loaded ("" when none)
    job_id: str = ""                   # the print job it belongs to ("" when loaded by hand)
    t_sim_s: float = 0.0               # the station's simulated clock
    elapsed_s: float = 0.0             # simulated time since the print started (frozen once it ended)
    total_s: float = 0.0               # elapsed plus remaining simulated time
    remaining_s: float = 0.0           # simulated time left (if resumed now, while paused)
    progress_r: float = f(default=0.0, ge=0.0, le=1.0)   # planned volume of the rows done over all (1: finished)
    deposited_mm3: float = 0.0         # volume deposited by the current print
    planned_mm3: float = 0.0           # volume the loaded program deposits in all
    layer: int = -1                    # layer being printed (0-based; -1 before the first)
    layers_total: int = 0              # layers of the loaded program
    rtf: float = 1.0                   # real-time factor: 1 = real time, larger = faster, 0 = as fast as possible
    speed_r: float = 1.0               # speed override (1 = programmed speeds)
    flow_r: float = 1.0                # flow override (1 = programmed flow)
    wobj_xyz_mm: list[float] = f(factory=lambda: [0.0, 0.0, 0.0], shape=(3,))    # work object now (calibrated):
                                       # the plate frame's origin in the robot base frame
    wobj_rpy_deg: list[float] = f(factory=lambda: [0.0, 0.0, 0.0], shape=(3,))   # its orientation in the base
                                       # frame: roll, pitch, yaw (R = Rz(yaw) Ry(pitch) Rx(roll))
    plate_clear: bool = True           # no part on the plate (false from a print's first bead to ``clear_plate``)
    plate_mm3: float = 0.0             # volume of the part on the plate (0 when clear)
    plate_job_id: str = ""             # the job whose part is on the plate ("" when clear or printed by hand)
    robot: RobotStatus | None = None   # the robot controller it drives (nil: the twin alone)


@schema("station.Event")
class Event:
    """One entry of the lossless event stream (``seq`` has no gaps)."""
    seq: int                     # from 1 for the station's first event; never restarts (it spans jobs and
                                 # restarts of the station), +1 per event
    t_sim_s: float               # the station's simulated clock when it happened
    kind: str                    # what happened: one of the kinds under "Events" in docs/protocol.md
    row: int = -1                # program row at that moment (-1: none)
    gcode_line: int = -1         # the G-code line of that row (1-based; -1: none)
    layer: int = -1              # layer at that moment (0-based; -1: none)
    data: dict[str, Any] = f(factory=dict)   # what the kind carries (see "Events")


@schema("station.EventsQuery", version=2)
class EventsQuery:
    """Events from ``since_seq`` on; ``kinds`` non-empty: only those kinds."""
    since_seq: int = f(default=0, ge=0)               # the first event wanted (inclusive; 0 and 1: from the first)
    limit: int = f(default=10000, ge=1, le=100000)    # the most events in the reply
    kinds: list[str] = f(factory=list)                # only these kinds (empty: every kind)


@schema("station.EventList", version=2)
class EventList:
    """Events from the log, oldest first; ``next_seq`` pages on, ``last_seq`` is the newest logged."""
    events: list[Event]          # oldest first
    next_seq: int                # the ``since_seq`` of the next page (the last event's seq + 1)
    last_seq: int = 0            # the newest event in the log (0: none yet)


@schema("station.TimeInfo")
class TimeInfo:
    """Simulation time: elapsed, total, remaining, and the estimate given at load (all simulated seconds)."""
    elapsed_s: float             # simulated time since the print started (0 before it starts)
    total_s: float               # elapsed plus remaining (simulated)
    remaining_s: float           # simulated time left to the end of the program (if resumed now, while paused)
    estimate_s: float            # the program's simulated duration estimated at load (or at a restart)
    state: str = ""              # the station's state


@schema("station.CellInfo")
class CellInfo:
    """The cell the station runs: its name, the arm, and each joint's limits (what a console draws the joints
    against, whichever cell it follows)."""
    name: str                    # the cell's name (a built-in cell's, ``fabric-cli cell list``, or its file's)
    description: str = ""        # the cell's own words
    robot: str = ""              # the arm's model (its URDF's name)
    brand: str = ""              # whose controller: abb, kuka, ur, franka, ... (which export is native)
    ik_family: str = ""          # the arm's inverse kinematics: closed forms opw, ur, panda; numeric (batched DLS)
    joint_names: list[str] = f(factory=list)    # A1..An, as the robot model names them
    lower_deg: list[float] = f(factory=list)    # each joint's lower limit, degrees
    upper_deg: list[float] = f(factory=list)    # each joint's upper limit, degrees
    fingerprint: str = ""        # hash of the cell's configuration (robot, tool, table, plate, home, approach)


@schema("station.LoadRequest")
class LoadRequest:
    """Load a planned program, fetched by id from the planner's artifact store."""
    program_id: str = f(max_len=128)     # the planner's program artifact id
    job_id: str = ""                     # the print job it belongs to (job events carry it; "": by hand)


@schema("station.StartRequest", version=2)
class StartRequest:
    """How to run: for ``start``, ``resume``, ``recover`` and ``rtf``.

    ``rtf`` 1 = real time, larger = faster, 0 = as fast as possible; nil keeps the current one.
    ``from_layer`` (0-based, as in events; -1 = not given): start or recover at that layer."""
    rtf: float | None = f(default=None, ge=0.0, le=1e6)       # real-time factor (nil: keep the current one)
    from_layer: int = f(default=-1, ge=-1, le=1_000_000)      # -1: from the beginning (start) or the
                                                              # interrupted spot (recover); ignored by resume and rtf


@schema("station.JogRequest")
class JogRequest:
    """Jog the nozzle: a straight move by ``dxyz_mm`` in the plate frame, the nozzle's orientation kept,
    collision-checked against the part on the plate. Only while the station is not printing (idle, ready,
    stopped, fault) and not moving."""
    dxyz_mm: list[float] = f(shape=(3,))                      # x, y, z in the plate frame (mm)
    speed_mm_s: float = f(default=20.0, ge=0.1, le=200.0)     # the move's speed


@schema("station.ExtrudeRequest")
class ExtrudeRequest:
    """Push (``length_mm`` > 0) or pull back (< 0) filament by hand, the robot still: a purge, a load, an
    unload. Refused with the nozzle below the material's minimum extrusion temperature, as printing is."""
    length_mm: float = f(ge=-100.0, le=500.0)                # filament length (not zero)
    speed_mm_s: float = f(default=2.0, ge=0.05, le=50.0)     # filament feed rate


@schema("station.Overrides")
class Overrides:
    """Live overrides; a nil field is left as it is. Speed and flow take effect from the next program row."""
    speed_r: float | None = f(default=None, ge=0.05, le=4.0)   # factor on programmed speeds
    flow_r: float | None = f(default=None, ge=0.0, le=4.0)     # factor on programmed flow
    nozzle_c: float | None = f(default=None, ge=0.0, le=500.0)  # nozzle set point (0: off)
    bed_c: float | None = f(default=None, ge=0.0, le=200.0)     # bed set point (0: off)


@schema("station.Check")
class Check:
    """One item of the ready checklist."""
    name: str                    # what is checked (e.g. ``services alive``, ``plate clear``)
    ok: bool                     # it passes
    detail: str = ""             # why it fails, or what was found


@schema("station.ReadyReport")
class ReadyReport:
    """The ready checklist: can a print start now."""
    ready: bool                  # every check passes
    checks: list[Check]          # the items, in a fixed order


@schema("station.Calibration")
class CalibrationReport:
    """The plate probed and the work object fitted to the touches (it replaces the work object)."""
    correction_xyz_mm: list[float]     # the fitted frame relative to the nominal one: offset, in the nominal frame
    correction_rpy_deg: list[float]    # and rotation: roll, pitch, yaw
    residual_rms_mm: float             # how well the touches agree with the fitted frame (RMS distance)
    points: int                        # touches probed
    wobj_xyz_mm: list[float]           # the work object now: the plate frame's origin in the robot base frame
    wobj_rpy_deg: list[float]          # its orientation in the base frame: roll, pitch, yaw


@schema("station.MeshRequest")
class MeshRequest:
    """The as-printed part: a mesh (``stl``, ``glb``) or the bead list (``csv``: one row per bead in
    deposition order, ``x0_mm,y0_mm,z0_mm,x1_mm,y1_mm,z1_mm,volume_mm3``, plate frame)."""
    fmt: str = f(default="stl", choices=MESH_FORMATS)    # stl (binary STL), glb (binary glTF) or csv
