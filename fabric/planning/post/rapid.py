"""ABB RAPID post-processor: a main module and print modules split at a configurable size.

Layout. ``<P>Main`` holds the tool (``tooldata``: the TCP in the flange frame),
the work object (``wobjdata``: the plate frame in the robot base frame; every
print target is a robtarget *in the plate frame* with ``\\WObj``), one
``speeddata`` / ``zonedata`` per distinct speed and zone, ``main`` calling
``Approach``, ``Print_1 .. Print_k`` and ``ReturnHome``. Each ``<P>Print_k``
module holds at most ``targets_per_module`` targets, because controllers
limit the size of a module (and of the program memory); approach and return
are joint moves written as ``MoveAbsJ`` with the planned joints, so they are
exact and need no configuration data.

Extruder. ``doExtruder`` (on/off) and ``aoFlow`` (volumetric rate in mm^3/s
at the programmed speed) are tied to the path with ``TriggL`` + ``TriggIO``
(``\\Start``, distance 0): the outputs switch exactly when the robot starts
the move that begins (or ends) extruding, not when the program pointer
passes, which would be early with zones. ``MoveLDO`` only switches at the end
point and has no analog output, so it was not used. Moves whose extrusion
does not change are plain ``MoveL``. Linear moves run with ``ConfL\\Off``:
the confdata written (quadrants of A1/A4/A6, and the sign of A5 in ``cfx``)
is informative; the planner's joints are continuous so the controller's
nearest configuration is the planned one.

Heaters and retraction go through signals a cell integrator maps:
``aoTempNozzle`` / ``aoTempBed`` (set points), ``diNozzleAtTemp`` /
``diBedAtTemp`` (waits) and the ``Retract`` procedure (``aoRetract`` length,
pulse on ``doRetract``).
"""
from __future__ import annotations

import re
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TextIO

import numpy as np

from fabric.ahead import AHEAD, WORKERS
from fabric.motion.program import MOVEJ, MOVEL, Program
from fabric.planning.post.common import (
    CHECK_ROWS,
    check_program,
    check_six_axes,
    row_blocks,
    write_ascii,
    write_lines,
)
from fabric.planning.post.numtext import ChoiceColumn, Column, FixedColumn, format_rows, trimmed_text
from fabric.planning.post.walk import (
    Block,
    Event,
    ExtruderOff,
    ExtruderOn,
    ExtruderRate,
    JointMove,
    LayerStart,
    LinearMove,
    LinearRun,
    Retract,
    RowWalker,
    SetTemp,
    Wait,
    WaitTemp,
)
from fabric.robot.frames import quat_from_R
from fabric.wire.errors import ValidationError

__all__ = ["RapidOptions", "RapidExport", "write_rapid"]

_IDENT = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,15}$")
_E9 = "[9E9,9E9,9E9,9E9,9E9,9E9]"
MOVEL_TEXT_ROWS = 50_000    # rows whose MoveL lines are formatted at once (aligned windows; runs of many modules)


@dataclass
class RapidOptions:
    """Names and sizes of the RAPID export (identifiers must be valid RAPID names)."""

    targets_per_module: int = 5000
    prefix: str = "AM"
    tool_name: str = "tExtruder"
    wobj_name: str = "wobjPlate"
    do_extruder: str = "doExtruder"
    ao_flow: str = "aoFlow"
    tool_mass_kg: float = 1.5
    tool_cog_mm: tuple[float, float, float] = (0.0, 0.0, 50.0)
    ori_speed_deg_s: float = 500.0
    joint_move_speed_mm_s: float = 150.0

    def __post_init__(self) -> None:
        if not 1 <= int(self.targets_per_module) <= 1_000_000:
            raise ValidationError("targets_per_module must be in 1..1000000", field="targets_per_module")
        for name in ("prefix", "tool_name", "wobj_name", "do_extruder", "ao_flow"):
            if not _IDENT.match(getattr(self, name)):
                raise ValidationError(f"{name} is not a RAPID identifier", field=name, value=getattr(self, name))
        if not (self.tool_mass_kg > 0 and self.ori_speed_deg_s > 0 and self.joint_move_speed_mm_s > 0):
            raise ValidationError("tool mass and speeds must be positive", field="tool_mass_kg")


@dataclass
class RapidExport:
    """What was written: module names in order and the number of targets in each."""

    modules: list[str] = field(default_factory=list)
    targets: list[int] = field(default_factory=list)


def _num(v: float, nd: int = 3) -> str:
    return trimmed_text(v, nd)


def _pose(xyz: np.ndarray, q: np.ndarray) -> str:
    pos = ",".join(_num(v) for v in xyz[:3])
    rot = ",".join(_num(v, 6) for v in q[:4])
    return f"[[{pos}],[{rot}]]"


class _Names:
    """speeddata / zonedata names for distinct (rounded) values."""

    def __init__(self, prefix: str, speeds: np.ndarray, zones: np.ndarray) -> None:
        self.prefix = prefix
        # keyed by Python's round(), as looked up (np.round differs from it next to a half: 66.65 -> 66.6, 66.7)
        speeds, zones = _run_values(speeds), _run_values(zones)
        speed_keys = sorted({round(float(v), 1) for v in np.unique(speeds)})
        zone_keys = sorted({round(float(z), 2) for z in np.unique(zones)})
        self.speeds = {v: f"v{prefix}{_num(v, 1).replace('.', '_')}" for v in speed_keys}
        self.zones = {z: f"z{prefix}{_num(z, 2).replace('.', '_')}" for z in zone_keys if z > 0}

    def speed(self, v: float) -> str:
        return self.speeds[round(float(v), 1)]

    def zone(self, z: float) -> str:
        z = round(float(z), 2)
        return "fine" if z <= 0 else self.zones[z]


def write_rapid(program: Program, sink: TextIO | Callable[[str], TextIO], *,
                tool_T: np.ndarray | None = None, options: RapidOptions | None = None) -> RapidExport:
    """Write ``program`` as RAPID modules.

    ``sink`` is either one text stream (all modules one after another, main
    first) or a callable ``module_name -> stream`` (e.g. one ``.mod`` file per
    module; the caller closes them). ``tool_T`` is the TCP in the flange frame
    (4x4, mm; identity if omitted).
    """
    check_program(program)
    check_six_axes(program, "RAPID")
    opt = options or RapidOptions()
    tool = np.eye(4) if tool_T is None else np.asarray(tool_T, dtype=float)
    moving = program.op <= MOVEL
    # the distinct speeds and zones, and where the print modules start: in blocks of rows (a program mapped
    # from files is read through once, holding a block at a time)
    speed_runs, zone_runs = [], []
    for a, b in row_blocks(0, len(program), CHECK_ROWS):
        m = moving[a:b]
        speed_runs.append(_run_values(_speeds(program, opt, slice(a, b))[m]))
        zone_runs.append(_run_values(program.zone_mm[a:b][m]))
        program.release_pages(a, b)
    names = _Names(opt.prefix, np.concatenate(speed_runs), np.concatenate(zone_runs))
    bounds = program.section_bounds()
    p0, p1 = bounds.get("Print", (0, 0))
    per = opt.targets_per_module
    cuts: list[int] = [p0]
    seen = 0
    for a, b in row_blocks(p0, p1, CHECK_ROWS):
        rows = np.flatnonzero(moving[a:b]) + a          # the motion rows of the print, numbered from seen
        nth = np.arange(max(per, -(-seen // per) * per), seen + len(rows), per)
        cuts += rows[nth - seen].tolist()
        seen += len(rows)
    cuts = sorted(set(cuts + [p1])) if p1 > p0 else []
    n_mod = max(len(cuts) - 1, 0)
    export = RapidExport()
    ctx = _Emitter(program, opt, names)
    main_name = f"{opt.prefix}Main"
    out = _open(sink, main_name)
    _write_main(out, main_name, program, opt, names, tool, n_mod, bounds, ctx)
    export.modules.append(main_name)
    export.targets.append(int(moving[slice(*bounds.get("Approach", (0, 0)))].sum()
                              + moving[slice(*bounds.get("ReturnHome", (0, 0)))].sum()))
    try:
        for k in range(n_mod):
            name = f"{opt.prefix}Print_{k + 1}"
            out = _open(sink, name)
            out.write(f"MODULE {name}\n  PROC Print_{k + 1}()\n")
            ctx.rows(out, cuts[k], cuts[k + 1])
            out.write("  ENDPROC\nENDMODULE\n")
            export.modules.append(name)
            export.targets.append(int(moving[cuts[k]:cuts[k + 1]].sum()))
    finally:
        ctx.movel.close()
    return export


def _speeds(program: Program, opt: RapidOptions, rows: slice | np.ndarray | int) -> np.ndarray:
    """The speed (mm/s) written for rows: a joint move's, or the row's programmed speed (joint moves' if none)."""
    v = np.where(program.op[rows] == MOVEJ, opt.joint_move_speed_mm_s, program.speed_mm_s[rows])
    return np.where(v > 0, v, opt.joint_move_speed_mm_s)


def _open(sink: TextIO | Callable[[str], TextIO], name: str) -> TextIO:
    return sink(name) if callable(sink) else sink


def _write_main(out: TextIO, name: str, program: Program, opt: RapidOptions, names: _Names,
                tool: np.ndarray, n_mod: int, bounds: dict[str, tuple[int, int]], ctx: _Emitter) -> None:
    tq = quat_from_R(tool[:3, :3])
    wq = quat_from_R(program.wobj[:3, :3])
    cog = ",".join(_num(c) for c in opt.tool_cog_mm)
    lines = [
        f"MODULE {name}",
        f"  ! am-fabric RAPID export: {int((program.op <= MOVEL).sum())} targets, {n_mod} print modules",
        f"  PERS tooldata {opt.tool_name} := [TRUE,{_pose(tool[:3, 3], tq)},"
        f"[{_num(opt.tool_mass_kg)},[{cog}],[1,0,0,0],0,0,0]];",
        f"  PERS wobjdata {opt.wobj_name} := [FALSE,TRUE,\"\",{_pose(program.wobj[:3, 3], wq)},[[0,0,0],[1,0,0,0]]];",
    ]
    lines += [f"  CONST speeddata {n} := [{_num(v, 1)},{_num(opt.ori_speed_deg_s, 1)},5000,1000];"
              for v, n in names.speeds.items()]
    lines += [f"  CONST zonedata {n} := [FALSE,{_num(z, 2)},{_num(1.5 * z, 2)},{_num(1.5 * z, 2)},"
              f"{_num(0.15 * z, 3)},{_num(1.5 * z, 2)},{_num(0.15 * z, 3)}];" for z, n in names.zones.items()]
    lines += [
        "  VAR triggdata trOn;", "  VAR triggdata trOff;", "  VAR triggdata trFlow;", "  VAR triggdata trFlowOff;",
        "", "  PROC main()", "    ConfL\\Off;", "    ExtruderInit;", "    Approach;",
        *[f"    Print_{k + 1};" for k in range(n_mod)],
        "    ReturnHome;", "  ENDPROC", "",
        "  PROC ExtruderInit()",
        f"    TriggIO trOn, 0\\Start\\DOp:={opt.do_extruder}, 1;",
        f"    TriggIO trOff, 0\\Start\\DOp:={opt.do_extruder}, 0;",
        f"    TriggIO trFlowOff, 0\\Start\\AOp:={opt.ao_flow}, 0;",
        "  ENDPROC", "",
        "  PROC Retract(num len_mm)",
        "    ! the extruder drive reads the length (mm, < 0 retracts) and moves on the pulse",
        "    SetAO aoRetract, len_mm;", "    PulseDO doRetract;", "  ENDPROC", "",
    ]
    write_lines(out, lines)
    for proc in ("Approach", "ReturnHome"):
        # the extruder is off entering these, whatever the print left it as
        out.write(f"  PROC {proc}()\n    SetDO {opt.do_extruder}, 0;\n    SetAO {opt.ao_flow}, 0;\n")
        ctx.walker.extruder_reset()
        if proc in bounds:
            ctx.rows(out, *bounds[proc])
        out.write("  ENDPROC\n")
    out.write("ENDMODULE\n")
    ctx.walker.extruder_reset()


class _Emitter:
    """Formats the walker's events as RAPID instructions; the walker keeps the extruder state across modules."""

    def __init__(self, program: Program, opt: RapidOptions, names: _Names) -> None:
        self.p, self.opt, self.names = program, opt, names
        self.walker = RowWalker(program, runs=True)
        self.tw = f"{opt.tool_name}\\WObj:={opt.wobj_name};"
        self.movel = _MoveLWindows(self)

    def rows(self, out: TextIO, start: int, stop: int) -> None:
        lines: list[str] = []
        for ev in self.walker.walk(start, stop):
            if isinstance(ev, (Block, LinearRun)):
                write_lines(out, lines)
                lines = []
            if isinstance(ev, Block):
                self._block(ev)
            elif isinstance(ev, LinearRun):
                write_ascii(out, self.movel.lines(ev.start, ev.stop))
            else:
                self._format(ev, lines)
        write_lines(out, lines)

    def movel_columns(self, rows: np.ndarray) -> list[Column]:
        """The columns of the ``MoveL`` lines of some linear-move rows."""
        p = self.p
        xyz, quat, q_deg = p.xyz_mm[rows], p.quat_wxyz[rows], np.degrees(p.q_rad[rows])
        cf, cfx = _confdata(q_deg)
        columns: list[Column] = [b"    MoveL [["]
        columns += _joined([FixedColumn(xyz[:, j], 3, trim=True) for j in range(3)])
        columns.append(b"],[")
        columns += _joined([FixedColumn(quat[:, j], 6, trim=True) for j in range(4)])
        columns.append(b"],[")
        columns += _joined([FixedColumn(cf[:, j], 0) for j in range(3)] + [FixedColumn(cfx, 0)])
        columns += [f"],{_E9}], ".encode(), _choices(_speeds(p, self.opt, rows), self.names.speed), b", ",
                    _choices(p.zone_mm[rows], self.names.zone), f", {self.tw}  ! ".encode(),
                    FixedColumn(p.gcode_line[rows], 0)]
        return columns

    def _block(self, block: Block) -> None:
        # joints in degrees and the confdata quadrants of the block's rows
        self.base = block.start
        self.q_deg = np.degrees(self.p.q_rad[block.start:block.stop])
        self.cf, self.cfx = _confdata(self.q_deg)

    def _format(self, ev: Event, lines: list[str]) -> None:
        p, opt = self.p, self.opt
        if isinstance(ev, LinearMove):
            i, k = ev.row, ev.row - self.base
            target = (f"[{_pose(p.xyz_mm[i], p.quat_wxyz[i])[1:-1]},[{self.cf[k, 0]},{self.cf[k, 1]},"
                      f"{self.cf[k, 2]},{self.cfx[k]}],{_E9}]")
            speed, zone = self.names.speed(float(_speeds(p, opt, i))), self.names.zone(p.zone_mm[i])
            sw = ev.extruder
            if isinstance(sw, (ExtruderOn, ExtruderRate)):
                lines.append(f"    TriggIO trFlow, 0\\Start\\AOp:={opt.ao_flow}, {_num(sw.rate_mm3_s)};")
                trigger = "trFlow\\T2:=trOn" if isinstance(sw, ExtruderOn) else "trFlow"
                lines.append(f"    TriggL {target}, {speed}, {trigger}, {zone}, {self.tw}  ! {p.gcode_line[i]}")
            elif isinstance(sw, ExtruderOff):
                lines.append(f"    TriggL {target}, {speed}, trOff\\T2:=trFlowOff, {zone}, {self.tw}"
                             f"  ! {p.gcode_line[i]}")
            else:
                lines.append(f"    MoveL {target}, {speed}, {zone}, {self.tw}  ! {p.gcode_line[i]}")
        elif isinstance(ev, JointMove):
            joints = ",".join(_num(v, 4) for v in self.q_deg[ev.row - self.base])
            speed = self.names.speed(float(_speeds(p, opt, ev.row)))
            lines.append(f"    MoveAbsJ [[{joints}],{_E9}]\\NoEOffs, {speed}, "
                         f"{self.names.zone(p.zone_mm[ev.row])}, {self.tw}")
        elif isinstance(ev, LayerStart):
            lines.append(f"    ! layer {ev.layer}")
        elif isinstance(ev, ExtruderOff):
            lines += [f"    SetDO {opt.do_extruder}, 0;", f"    SetAO {opt.ao_flow}, 0;"]
        elif isinstance(ev, Wait):
            lines.append(f"    WaitTime {_num(ev.duration_s)};")
        elif isinstance(ev, SetTemp):
            lines.append(f"    SetAO aoTemp{ev.heater.capitalize()}, {_num(ev.temp_c, 1)};")
        elif isinstance(ev, WaitTemp):
            lines.append(f"    WaitDI di{ev.heater.capitalize()}AtTemp, 1;")
        elif isinstance(ev, Retract):
            lines.append(f"    Retract {_num(ev.length_mm)};")


def _joined(columns: list[FixedColumn]) -> list[Column]:
    """The columns with a comma between each two."""
    out: list[Column] = []
    for k, col in enumerate(columns):
        out += [b",", col] if k else [col]
    return out


def _run_starts(values: np.ndarray) -> np.ndarray:
    """Where each run of equal consecutive values starts."""
    return np.concatenate([[0], np.flatnonzero(values[1:] != values[:-1]) + 1]) if len(values) else np.zeros(0, int)


def _run_values(values: np.ndarray) -> np.ndarray:
    """The value of each run of equal consecutive values (the same distinct values, far fewer to sort)."""
    return values[_run_starts(values)]


def _choices(values: np.ndarray, name_of: Callable[[float], str]) -> ChoiceColumn:
    """A column of names (speeddata / zonedata) of per-row values, each distinct value named once.

    Speeds and zones change rarely along a path: the values are taken as runs
    of equal values, and only the runs' values are sorted out.
    """
    if len(values) == 0:
        return ChoiceColumn(np.zeros(0, dtype=np.intp), [])
    starts = _run_starts(values)
    distinct, run_index = np.unique(values[starts], return_inverse=True)
    index = np.repeat(run_index, np.diff(np.append(starts, len(values))))
    return ChoiceColumn(index, [name_of(v).encode() for v in distinct])


def _confdata(q_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The confdata quadrants ``cf1, cf4, cf6`` (M, 3) and ``cfx`` (M,) of joints in degrees."""
    return np.floor(q_deg[:, [0, 3, 5]] / 90.0).astype(int), (q_deg[:, 4] < 0).astype(int)


@dataclass
class _MoveLText:
    """The ``MoveL`` lines of the linear moves among some rows, formatted at once; a run is a slice of them.

    RAPID walks the print one module (a few thousand targets) at a time, so
    formatting each run on its own would pay the set-up of the columns once per
    module: the lines of ``MOVEL_TEXT_ROWS`` rows are formatted together instead.
    """

    rows: np.ndarray           # (M,) the linear-move rows, ascending
    text: bytes                # their lines
    starts: np.ndarray         # (M + 1,) where each line starts in ``text`` (and the end)

    @classmethod
    def of(cls, emitter: _Emitter, start: int, stop: int) -> _MoveLText:
        p = emitter.p
        stop = min(stop, len(p))
        rows = np.flatnonzero(p.op[start:stop] == MOVEL) + start
        text = format_rows(emitter.movel_columns(rows), sep=b"")
        ends = np.flatnonzero(np.frombuffer(text, dtype=np.uint8) == ord("\n")) + 1
        return cls(rows, text, np.concatenate([[0], ends]))

    def lines(self, start: int, stop: int) -> bytes:
        """The lines of rows ``[start, stop)``, all linear moves."""
        k = int(np.searchsorted(self.rows, start))
        return self.text[self.starts[k]:self.starts[k + stop - start]]


class _MoveLWindows:
    """``MoveL`` lines by aligned windows of ``MOVEL_TEXT_ROWS`` rows; the windows after the one in use are
    formatted ahead by ``WORKERS`` threads (numpy lets go of the interpreter lock: both cores format
    while the walker writes). Memory: ``1 + AHEAD`` windows."""

    def __init__(self, emitter: _Emitter) -> None:
        self.emitter = emitter
        self.n_rows = len(emitter.p)
        self._pool = ThreadPoolExecutor(max_workers=WORKERS, thread_name_prefix="export-format")
        self._windows: dict[int, Future[_MoveLText]] = {}

    def lines(self, start: int, stop: int) -> bytes:
        """The lines of rows ``[start, stop)``, all linear moves (a run may span two windows)."""
        first, last = start // MOVEL_TEXT_ROWS, (stop - 1) // MOVEL_TEXT_ROWS
        parts = []
        for k in range(first, last + 1):
            a, b = max(start, k * MOVEL_TEXT_ROWS), min(stop, (k + 1) * MOVEL_TEXT_ROWS)
            parts.append(self._window(k).lines(a, b))
        for k in [k for k in self._windows if k < last]:     # walked past: forget
            del self._windows[k]
        for k in range(last + 1, last + 1 + AHEAD):
            if k * MOVEL_TEXT_ROWS < self.n_rows:
                self._window_future(k)                        # format the next ones ahead
        return parts[0] if len(parts) == 1 else b"".join(parts)

    def _window(self, k: int) -> _MoveLText:
        return self._window_future(k).result()

    def _window_future(self, k: int) -> Future[_MoveLText]:
        fut = self._windows.get(k)
        if fut is None:
            a = k * MOVEL_TEXT_ROWS
            fut = self._windows[k] = self._pool.submit(_MoveLText.of, self.emitter, a, a + MOVEL_TEXT_ROWS)
        return fut

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)
