"""What planning produced: reachability by row and G-code line, statistics, the result object."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fabric.gcode.material import Material
from fabric.gcode.toolpath import Toolpath
from fabric.motion.cold import ColdExtrusion
from fabric.motion.program import Program
from fabric.planning.envelope import ENV_BELOW_PLATE, ENV_OFF_PLATE, ENVELOPE_REASONS
from fabric.planning.material import ResolvedMaterial, resolve_material
from fabric.robot.kinematics import IK_JOINT_LIMIT, IK_JUMP, IK_OK, IK_OUT_OF_REACH, IK_REASONS, IK_SINGULAR
from fabric.wire.errors import ColdExtrusionError, UnreachableError

__all__ = ["Reachability", "PlanStats", "PlanResult", "UNREACHABLE_CODES", "TargetWhy", "target_why",
           "unreachable_detail", "joints_at_fault"]

# Statuses a program cannot run through. IK_SINGULAR rows have an exact
# solution (the motion model slows the TCP there): reported, not fatal. Targets outside the work
# envelope (fabric.planning.envelope) are fatal too unless the user allows them.
UNREACHABLE_CODES = (IK_OUT_OF_REACH, IK_JOINT_LIMIT, IK_JUMP, ENV_OFF_PLATE, ENV_BELOW_PLATE)
REASONS = {**IK_REASONS, **ENVELOPE_REASONS}
MULTIAXIS_CELL = "irb140-multiaxis"   # the built-in cell whose wrist stays bent under a tilted nozzle
WRIST_NEAR_SIN = float(np.sin(np.radians(2.0)))      # a wrist bent less than this is at its singularity


@dataclass
class Reachability:
    """Per-row status of a program (non-motion rows repeat the previous row's status): the IK's, or where
    a target leaves the work envelope, why (unless allowed: then the IK's, and the envelope only counted)."""

    status: np.ndarray                        # (N,) uint8, IK_* codes, ENV_* codes
    rot_deg: np.ndarray                       # (N,) chosen rotation about the nozzle axis
    feasible_r: float                         # fraction of motion rows that are reachable
    counts: dict[str, int] = field(default_factory=dict)   # motion rows by reason
    first_unreachable: tuple[int, str] | None = None        # (G-code line, reason)
    first_unreachable_row: int = -1
    cold: ColdExtrusion | None = None        # the first move extruding below the material's minimum
    by_joint: dict[str, int] = field(default_factory=dict)  # joint-limit and joint-jump targets by joint at fault

    @classmethod
    def from_status(cls, status: np.ndarray, rot_deg: np.ndarray, motion: np.ndarray,
                    gcode_line: np.ndarray, envelope: np.ndarray | None = None,
                    allow_off_plate: bool = False) -> Reachability:
        """The report of IK ``status`` and, if given, the ``envelope`` statuses (0 inside) of the same rows."""
        allowed: dict[str, int] = {}
        if envelope is not None and envelope.any():
            if allow_off_plate:             # counted, not fatal: the IK's status stays
                allowed = {REASONS[c]: int(n) for c, n in enumerate(np.bincount(envelope[motion])) if n and c}
            else:
                status = np.where(envelope > 0, envelope, status).astype(np.uint8)
        st = status[motion]
        counts = {REASONS.get(c, f"status {c}"): int(n) for c, n in enumerate(np.bincount(st)) if n}
        for reason, n in allowed.items():
            counts[reason] = counts.get(reason, 0) + n
        bad = motion & np.isin(status, UNREACHABLE_CODES)
        first = None
        row = -1
        if bad.any():
            row = int(np.argmax(bad))
            first = (_line_of(gcode_line, row), REASONS[int(status[row])])
        ok = ~np.isin(st, UNREACHABLE_CODES)
        return cls(status=status, rot_deg=rot_deg, feasible_r=float(ok.mean()) if len(st) else 1.0,
                   counts=counts, first_unreachable=first, first_unreachable_row=row)

    @property
    def reachable(self) -> bool:
        return self.first_unreachable is None

    @property
    def runnable(self) -> bool:
        """Every target reachable and no move extruding cold."""
        return self.first_unreachable is None and self.cold is None

    @property
    def n_singular(self) -> int:
        return self.counts.get(IK_REASONS[IK_SINGULAR], 0)

    @property
    def n_ok(self) -> int:
        return self.counts.get(IK_REASONS[IK_OK], 0)


def _line_of(gcode_line: np.ndarray, row: int) -> int:
    """The G-code line of ``row``; for a row of no line of its own (the approach above the first point,
    the move up from the last one), the line of the point it moves to or from: the next row that has a
    line, else the one before."""
    if gcode_line[row] >= 0:
        return int(gcode_line[row])
    after = np.flatnonzero(gcode_line[row:] >= 0)
    if len(after):
        return int(gcode_line[row + after[0]])
    before = np.flatnonzero(gcode_line[:row] >= 0)
    return int(gcode_line[before[-1]]) if len(before) else -1


@dataclass
class PlanStats:
    """Figures of a plan (lengths in mm, volume in mm^3, times in s)."""

    moves: int = 0                 # toolpath segments
    rows: int = 0                  # program rows
    targets: int = 0               # program motion rows
    layers: int = 0
    extruded_volume_mm3: float = 0.0
    path_length_mm: float = 0.0    # TCP path of the Print section
    print_length_mm: float = 0.0   # of it, while extruding
    travel_lifts: int = 0
    fan_events_dropped: int = 0    # M106/M107: no robot instruction carries them
    gcode_lines: int = 0
    unknown_commands: dict[str, int] = field(default_factory=dict)
    slicer: str = "unknown"
    material: ResolvedMaterial = field(default_factory=lambda: resolve_material(Material(), None))
    warnings: list[str] = field(default_factory=list)     # what the user should know (an assumed material...)
    split_rows: int = 0            # rows added splitting linear moves (fabric/planning/refine.py)
    parse_s: float = 0.0
    ik_s: float = 0.0
    refine_s: float = 0.0          # checking and splitting the linear moves
    timing_s: float = 0.0
    total_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        from dataclasses import asdict
        return asdict(self)


@dataclass(frozen=True)
class TargetWhy:
    """Why one target is unreachable, in words (``detail``, "" when the reason says it all) and as figures: the
    joint at fault (1-based: A1 = 1; 0 for none), its angle there (deg) and, at a joint limit, the limit it
    passes (deg)."""

    detail: str = ""
    joint: int = 0
    value_deg: float | None = None
    limit_deg: float | None = None


def unreachable_detail(program: Program, row: int, reason: str, cell_name: str = "", robot: Any = None) -> str:
    """The words of :func:`target_why`."""
    return target_why(program, row, reason, cell_name, robot).detail


def target_why(program: Program, row: int, reason: str, cell_name: str = "", robot: Any = None) -> TargetWhy:
    """The first unreachable target's reason in more words and figures (``robot``: the cell's
    :class:`~fabric.robot.model.RobotModel`, for its joint limits and wrist):

    * joint limit: the joint furthest past its limit, its angle and the limit (``A5 at 123.0 deg, past its
      limit 115 deg``), as the arm's configuration there has them;
    * joint jump: which joint turns and by how much, and where the wrist passes its singularity; for a tilted
      nozzle (a multi-axis program) whose jump is in the wrist, that the cell's wrist cannot follow the tilt
      (and, on another cell than :data:`MULTIAXIS_CELL`, that one can);
    * out of reach: how far the tip is from the robot's base.
    """
    if not 0 <= row < len(program):
        return TargetWhy()
    q_deg = np.degrees(program.q_rad[row])
    if reason == "joint limit" and robot is not None:
        return _past_limit(q_deg, np.degrees(robot.lower_rad), np.degrees(robot.upper_rad))
    if reason == "out of reach":
        tip = program.wobj[:3, :3] @ program.xyz_mm[row] + program.wobj[:3, 3]
        return TargetWhy(f"the nozzle tip would be {float(np.linalg.norm(tip)):.0f} mm from the robot's base "
                         f"(base frame {np.round(tip).astype(int).tolist()} mm), beyond what the arm reaches")
    wrist = ""
    if program.meta.get("multiaxis", False):
        wrist = ("; the tilted nozzle turns the wrist past a limit or through its singularity, so this cell "
                 "cannot follow the tilt continuously")
        if cell_name != MULTIAXIS_CELL:
            wrist += f" (a cell whose wrist stays bent can: {MULTIAXIS_CELL})"
    if reason == "joint jump" and row > 0:
        step = np.abs(q_deg - np.degrees(program.q_rad[row - 1]))
        j = int(np.argmax(step))
        text = f"A{j + 1} turns {step[j]:.0f} deg between two neighbouring targets, a change of configuration"
        text += _at_singularity(program, row, robot)
        return TargetWhy(text + (wrist if j >= 3 else ""), joint=j + 1, value_deg=float(q_deg[j]))
    if reason == "singular" and wrist:
        return TargetWhy("the wrist is straight" + wrist)
    return TargetWhy()


def _past_limit(q_deg: np.ndarray, lower_deg: np.ndarray, upper_deg: np.ndarray) -> TargetWhy:
    """The joint furthest past a limit (or, within rounding of them all, the one nearest its limit)."""
    over = np.maximum(lower_deg - q_deg, q_deg - upper_deg)
    j = int(np.argmax(over))
    limit = float(upper_deg[j] if q_deg[j] - upper_deg[j] >= lower_deg[j] - q_deg[j] else lower_deg[j])
    past = "past its limit" if over[j] > 0.0 else "at its limit"
    return TargetWhy(f"A{j + 1} at {q_deg[j]:.1f} deg, {past} {limit:g} deg", joint=j + 1,
                     value_deg=float(q_deg[j]), limit_deg=limit)


def _at_singularity(program: Program, row: int, robot: Any) -> str:
    """", through the wrist singularity (A5 at 0.4 deg)" where the wrist is (nearly) straight at ``row``."""
    cf = getattr(robot, "closed_form", None)
    if cf is None:
        return ""
    sin = cf.wrist_sin(program.q_rad[row - 1:row + 1])
    if float(sin.min()) >= WRIST_NEAR_SIN:
        return ""
    return f", through the wrist singularity (A5 at {np.degrees(program.q_rad[row, 4]):.1f} deg)"


def joints_at_fault(q_rad: np.ndarray, status: np.ndarray, motion: np.ndarray, lower_rad: np.ndarray,
                    upper_rad: np.ndarray) -> dict[str, int]:
    """Targets at a joint limit or a joint jump counted by the joint at fault (``{"A5": 338}``): the joint
    furthest past its limit, the joint that turns most from the target before."""
    out: dict[str, int] = {}
    limit = np.flatnonzero(motion & (status == IK_JOINT_LIMIT))
    if len(limit):
        q = q_rad[limit]
        over = np.maximum(lower_rad - q, q - upper_rad)
        for j, n in enumerate(np.bincount(np.argmax(over, axis=1), minlength=q_rad.shape[1])):
            if n:
                out[f"A{j + 1}"] = out.get(f"A{j + 1}", 0) + int(n)
    jump = np.flatnonzero(motion & (status == IK_JUMP))
    jump = jump[jump > 0]
    if len(jump):
        step = np.abs(q_rad[jump] - q_rad[jump - 1])
        for j, n in enumerate(np.bincount(np.argmax(step, axis=1), minlength=q_rad.shape[1])):
            if n:
                out[f"A{j + 1}"] = out.get(f"A{j + 1}", 0) + int(n)
    return out


@dataclass
class PlanResult:
    """A planned G-code file: the program, its reachability, the cycle-time estimate and stats."""

    program: Program
    report: Reachability
    estimate_s: float
    stats: PlanStats
    toolpath: Toolpath | None = None
    slowed_rows: np.ndarray | None = None     # rows whose speed a joint velocity limit capped
    slowed_joint: np.ndarray | None = None    # the limiting joint (0-based) of each
    t_end_s: np.ndarray | None = None         # time each row ends, from home (the estimate's timeline)

    def require_runnable(self) -> PlanResult:
        """Raise :class:`UnreachableError` naming the first unreachable G-code line, or
        :class:`ColdExtrusionError` naming the first line that would extrude cold; else return self."""
        first = self.report.first_unreachable
        if first is not None:
            line, reason = first
            row = self.report.first_unreachable_row
            xyz = self.program.xyz_mm[row].round(3).tolist()
            raise UnreachableError(f"G-code line {line}: target {xyz} (plate frame, mm) is not reachable: {reason}",
                                   gcode_line=line, reason=reason, row=row, xyz_mm=xyz,
                                   counts=dict(self.report.counts))
        cold = self.report.cold
        if cold is not None:
            raise ColdExtrusionError(cold.message, **cold.details())
        return self
