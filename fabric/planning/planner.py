"""The planner: G-code -> verified joint program (approach, print, return home) with its report.

Pipeline, chunk by chunk of the toolpath (``ik_block_rows`` rows each, cut
between two extruding moves, :class:`fabric.gcode.ToolpathChunks`, so memory
holds a chunk, not the file): parse (streamed in blocks) -> map the toolpath to
Print rows in the plate frame (:mod:`fabric.planning.mapping`) -> frame the print with an
*Approach* (a joint move from home to ``approach_height_mm`` above the first
point, then a linear move down, at the cell's approach speed, fine zones) and a
*Return home* (a linear move up, a joint move to the home joints) -> inverse
kinematics of every motion row with the free rotation about the nozzle axis
(``fabric.robot.path_ik.solve_path``), solved in blocks of ``ik_block_rows``
seeded with the previous block's last joints so memory stays bounded and
progress can be reported (:mod:`fabric.planning.chunk_ik`) -> linear moves
split where their joints, interpolated between two rows, would leave the
straight line (:mod:`fabric.planning.refine`) -> the chunk's rows appended to a sink (in memory, or
files the program is mapped from: :mod:`fabric.motion.program_file`) -> once the
whole program is there, the cycle time from the motion model the station
executes (``fabric.motion.timing.program_times``, in blocks of rows too).

Frames: program targets are the TCP in the plate frame (the work object
``cell.wobj_T()``); IK takes them in the robot base frame, ``wobj_T @ p``, with
the nozzle axis ``R_wobj @ axis``. Joint moves carry ``vel_r`` so that they
cover their TCP distance at about the approach speed: ``vel_r = max_j(|dq_j| /
vlim_j) * v / distance`` (clipped to [0.01, 1]), the paper's "joint moves at
150 mm/s".
"""
from __future__ import annotations

import dataclasses
import os
import queue
import re
import threading
import time
from collections.abc import Callable, Generator, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from fabric.gcode import Toolpath, ToolpathChunks
from fabric.gcode.interp import ChunkSummary
from fabric.gcode.material import Material
from fabric.motion.cold import first_cold_extrusion
from fabric.motion.program import APPROACH, MOVEJ, MOVEL, PRINT, RETURN_HOME, SET_TEMP, WAIT, WAIT_TEMP, Program
from fabric.motion.program_file import FileSink, MemorySink, ProgramSink
from fabric.planning.chunk_ik import JUMP_DEG, Seed, solve_chunk
from fabric.planning.envelope import envelope_status, floating_warning
from fabric.planning.mapping import map_toolpath
from fabric.planning.material import resolve_material
from fabric.planning.options import PlanOptions
from fabric.planning.post.names import program_name
from fabric.planning.refine import PrevRow, reach_bound_mm, refine_linear
from fabric.planning.report import PlanResult, PlanStats, Reachability, joints_at_fault
from fabric.planning.tally import Assembled, Reach, Totals
from fabric.planning.turns import split_turns
from fabric.robot.frames import inv_T
from fabric.wire.errors import FabricError, ValidationError

__all__ = ["plan_gcode", "plan_gcode_file", "plan_toolpath"]

Progress = Callable[[float], None]
ProgramReady = Callable[[Program, Reachability], None]     # told the program (and its reach) once it is final
TimesSoFar = Callable[[np.ndarray, int], None]             # told the rows' times array and how many are computed


def _sub(progress: Progress | None, a: float, b: float) -> Progress | None:
    """A progress callback mapping [0, 1] onto [a, b] of ``progress``."""
    if progress is None:
        return None
    return lambda f: progress(a + (b - a) * min(max(f, 0.0), 1.0))


def plan_gcode(text: str | bytes | os.PathLike[str], cell: Any, options: PlanOptions | None = None,
               progress: Progress | None = None, filename: str | None = None,
               on_program: ProgramReady | None = None, program_dir: str | os.PathLike[str] | None = None,
               on_times: TimesSoFar | None = None) -> PlanResult:
    """Plan G-code held in memory, or in a file named by a path, for ``cell`` (a :class:`fabric.robot.cell.Cell`).

    ``filename`` (optional) names the job: the program's ``meta`` gets
    ``filename`` and ``name`` (its stem), which exports use. ``on_program`` is
    called with the program as soon as it is final, before the cycle-time
    estimate, with its reachability (e.g. to start encoding or exporting it on another thread); it must
    not change either. With ``program_dir`` the program (and its per-row status, rotation and times) is
    written to files there and mapped back read-only (:class:`~fabric.motion.program_file.FileSink`): the
    process then holds a chunk of rows at a time, whatever the file's size; without it the program is
    built in memory. ``on_times(t_end_s, rows)`` is told, as the cycle time is computed block by block, that
    the first ``rows`` rows' times are in ``t_end_s`` (a runnable program only; e.g. to stream a CSV behind it).
    """
    opt = options or PlanOptions()
    chunks = ToolpathChunks(text, chunk_rows=opt.ik_block_rows, chord_tol_mm=opt.chord_tol_mm)
    meta = {"filename": Path(filename).name, "name": program_name(Path(filename).stem)} if filename else {}
    if program_dir is not None:
        sink: ProgramSink = FileSink(program_dir, extra=_EXTRA, nq=cell.robot.nq)
    else:
        sink = MemorySink(rows_hint=chunks.size // 12 + 64, extra=_EXTRA, nq=cell.robot.nq)
    return _plan_chunks(chunks, cell, opt, progress, meta=meta, on_program=on_program, sink=sink, on_times=on_times)


def plan_gcode_file(path: str | os.PathLike[str], cell: Any, options: PlanOptions | None = None,
                    progress: Progress | None = None) -> PlanResult:
    """Plan a G-code file, streaming it in blocks."""
    return plan_gcode(Path(path), cell, options, progress, filename=str(path))


def _assemble(tp: Toolpath, cell: Any, opt: PlanOptions, first: bool = True, last: bool = True
              ) -> tuple[Program, Assembled]:
    """Program rows of a toolpath chunk (plate frame, no joints yet): the approach before the first chunk's
    print rows, the return home after the last's. A multi-axis chunk approaches and leaves along the nozzle
    axis of its first and last point (straight down and up for a vertical nozzle)."""
    head, tail = (2 if first else 0), (2 if last else 0)
    if tp.multiaxis and any(opt.tilt_deg):
        raise ValidationError("tilt_deg tilts the nozzle of planar G-code; this multi-axis G-code states the "
                              "nozzle axis of every move (I J K): plan it with tilt_deg 0", field="tilt_deg",
                              value=list(opt.tilt_deg))
    pr = map_toolpath(tp, opt, head=head, tail=tail, first=first, last=last)
    h = opt.approach_height_mm or float(cell.approach_height_mm)
    v_app = min(opt.approach_speed_mm_s or float(cell.approach_speed_mm_s), opt.max_tcp_speed_mm_s)
    up = h * pr.first_axis
    n = len(pr.op)
    cols = {name: getattr(pr, name) for name in ("op", "xyz_mm", "speed_mm_s", "zone_mm", "flow_mm3_mm",
                                                 "value", "aux", "gcode_line", "layer")}
    section = np.full(n, PRINT, np.uint8)
    if first:
        section[:2] = APPROACH
    if last:
        section[-2:] = RETURN_HOME
    quat = np.zeros((n, 4))
    quat[:, 0] = 1.0
    prog = Program(**cols, section=section, q_rad=np.zeros((n, int(cell.robot.nq))), quat_wxyz=quat,
                   vel_r=np.zeros(n),
                   wobj=np.asarray(cell.wobj_T() if opt.wobj_T is None else opt.wobj_T, dtype=float))
    if first:
        prog.op[:2] = (MOVEJ, MOVEL)
        prog.xyz_mm[0], prog.xyz_mm[1] = pr.first_xyz_mm + up, pr.first_xyz_mm
        prog.speed_mm_s[[0, 1]] = v_app
        prog.zone_mm[[0, 1]] = 0.0
        prog.gcode_line[1] = pr.first_line
    if last:
        end = prog.xyz_mm[pr.stop - 1] if len(pr) else pr.first_xyz_mm
        prog.op[-2:] = (MOVEL, MOVEJ)
        prog.xyz_mm[-2] = end + (up if pr.axis is None else h * pr.axis[-2])
        prog.speed_mm_s[[-2, -1]] = v_app
        prog.zone_mm[[-2, -1]] = 0.0
    dropped = dropped_lifts = 0
    axis = pr.axis
    if first:
        prog, dropped, dropped_lifts, axis = _start_at_first_bead(prog, pr.stop, axis)
    n = len(prog)
    # non-motion rows (temperatures, waits, retractions) hold the TCP where the last motion row left it (a
    # chunk after the first starts with a move: the cut is between two extruding moves)
    motion = prog.op <= MOVEL
    last_motion = np.maximum.accumulate(np.where(motion, np.arange(n), 0))
    rest = np.flatnonzero(~motion)
    prog.xyz_mm[rest] = prog.xyz_mm[last_motion[rest]]
    if axis is not None:
        axis[rest] = axis[last_motion[rest]]
    return prog, Assembled(print_rows=len(pr) - dropped, lifts=pr.n_lifts - dropped_lifts,
                            fan_events=pr.n_fan_events, approach_speed_mm_s=v_app, leading_dropped=dropped,
                            axis=axis)


def _start_at_first_bead(prog: Program, stop: int, axis: np.ndarray | None = None
                         ) -> tuple[Program, int, int, np.ndarray | None]:
    """Approach the first bead directly, heating at the approach height.

    A slicer's file starts at the bed origin: heat, then travel to the part. A
    robot should not park its nozzle 0.3 mm over the plate corner while it
    heats: the travel moves before the first extruding move are dropped (the
    approach's linear move goes straight down to where the first bead starts),
    and the leading temperature and wait rows run between the approach's joint
    move and that linear move, i.e. at the approach height. Returns the new
    program, how many travel rows were dropped and how many lifted travels they
    held (a lifted travel is three rows of one G-code line: up, across, down).
    """
    body = np.arange(2, stop)
    extruding = body[(prog.op[body] == MOVEL) & (prog.flow_mm3_mm[body] > 0)]
    if len(extruding) == 0:
        return prog, 0, 0, axis
    lead = np.arange(2, int(extruding[0]))
    travel = lead[prog.op[lead] <= MOVEL]
    heat = lead[np.isin(prog.op[lead], (WAIT, SET_TEMP, WAIT_TEMP))]
    other = lead[(prog.op[lead] > MOVEL) & ~np.isin(prog.op[lead], (WAIT, SET_TEMP, WAIT_TEMP))]
    if len(travel):
        if axis is None:
            prog.xyz_mm[0] = prog.xyz_mm[travel[-1]] + (prog.xyz_mm[0] - prog.xyz_mm[1])
        else:                                     # the approach comes down along the first bead's axis
            height = float(np.linalg.norm(prog.xyz_mm[0] - prog.xyz_mm[1]))
            axis[0] = axis[1] = axis[travel[-1]]
            prog.xyz_mm[0] = prog.xyz_mm[travel[-1]] + height * axis[0]
        prog.xyz_mm[1] = prog.xyz_mm[travel[-1]]
        prog.gcode_line[1] = prog.gcode_line[travel[-1]]
    prog.section[heat] = APPROACH
    lifts = (len(travel) - len(np.unique(prog.gcode_line[travel]))) // 2
    # rewrite only the short prefix [0, f): its new rows land in [k, f) and the program becomes the view [k:],
    # so a million-row program is not copied
    f, k = int(extruding[0]), len(travel)
    order = np.concatenate([[0], heat, [1], other]).astype(np.intp)
    cols = {}
    for name, col in prog.columns().items():
        col[k:f] = col[order].copy()
        cols[name] = col[k:]
    if axis is not None:
        axis[k:f] = axis[order].copy()
        axis = axis[k:]
    return Program(**cols, wobj=prog.wobj, meta=prog.meta), k, lifts, axis


def _joint_speeds(prog: Program, cell: Any, v_mm_s: float) -> None:
    """``vel_r`` of the joint moves: cover the TCP distance at about ``v_mm_s`` (see module doc)."""
    robot = cell.robot
    vlim = np.asarray(robot.vel_limit_rad_s, dtype=float)
    home = np.asarray(cell.home_q_rad, dtype=float)
    T_home = inv_T(prog.wobj) @ robot.fk(home[None])[0]
    for i in np.flatnonzero(prog.op == MOVEJ):
        q0, p0 = (home, T_home[:3, 3]) if i == 0 else (prog.q_rad[i - 1], prog.xyz_mm[i - 1])
        dist = float(np.linalg.norm(prog.xyz_mm[i] - p0))
        t_full = float(np.max(np.abs(prog.q_rad[i] - q0) / vlim))
        prog.vel_r[i] = 1.0 if dist < 1e-6 else float(np.clip(t_full * v_mm_s / dist, 0.01, 1.0))


def plan_toolpath(tp: Toolpath, cell: Any, options: PlanOptions | None = None,
                  progress: Progress | None = None, *, parse_s: float = 0.0, meta: dict[str, Any] | None = None,
                  on_program: ProgramReady | None = None) -> PlanResult:
    """Plan an interpreted toolpath, whole in memory, for ``cell`` (see the module docstring).

    ``meta`` is added to the program's; ``on_program`` gets the program once it is final (see :func:`plan_gcode`).
    """
    opt = options or PlanOptions()
    sink = MemorySink(rows_hint=2 * len(tp) + 64, extra=_EXTRA, nq=cell.robot.nq)
    return _plan_chunks(_Whole(tp), cell, opt, progress, meta=meta or {}, on_program=on_program,
                        sink=sink, parse_s=parse_s)


# per-row columns kept beside the program: its reach
_EXTRA: dict[str, tuple[str, tuple[int, ...]]] = {"status": ("u1", ()), "rot_deg": ("f8", ())}


_WIDTH = re.compile(rb"^;WIDTH:\s*([0-9]*\.?[0-9]+)", re.M)


def _stated_width(head: bytes) -> dict[str, float]:
    """``{"bead_width_mm": w}`` from the first ``;WIDTH:`` marker of a multi-axis file's first bytes (its
    curved-layer beads are that wide; their height varies with the flow), or nothing when there is none."""
    m = _WIDTH.search(head)
    if m is None:
        return {}
    w = float(m.group(1))
    return {"bead_width_mm": w} if 0.0 < w < 100.0 else {}


class _Whole:
    """A whole toolpath as the one chunk of :func:`_plan_chunks`."""

    def __init__(self, tp: Toolpath) -> None:
        self.tp, self.slicer, self.fraction, self.toolpath = tp, tp.slicer, 1.0, tp
        self.multiaxis = tp.multiaxis
        self.summary = ChunkSummary(n_lines=tp.n_lines, n_rows=len(tp), layer_z_mm=tp.layer_z_mm,
                                    unknown_commands=dict(tp.unknown_commands), feature_names=list(tp.feature_names))

    def material(self, n_lines: int = 0) -> Material:
        return self.tp.material

    def __iter__(self) -> Iterator[tuple[Toolpath, bool]]:
        yield self.tp, True


class _Progress:
    """A progress callback that never goes back (the parser reads a little ahead of the chunks planned)."""

    def __init__(self, fn: Progress | None) -> None:
        self.fn, self.last = fn, 0.0

    def __call__(self, fraction: float) -> None:
        if self.fn is None:
            return
        self.last = max(self.last, min(max(float(fraction), 0.0), 1.0))
        self.fn(self.last)

    def sub(self, a: float, b: float) -> Progress:
        return lambda f: self(a + (b - a) * f)


def _parsed_ahead(chunks: Iterable[tuple[Toolpath, bool]]) -> Iterator[tuple[Toolpath, bool]]:
    """The chunks, parsed by a worker thread one chunk ahead of the caller, which maps and solves the one before
    meanwhile (on the other core: NumPy lets go of the interpreter lock). An error of the parser is raised
    where its chunk would have come; a caller that stops early stops the worker."""
    done = object()
    handoff: queue.Queue[Any] = queue.Queue(maxsize=1)
    stop = threading.Event()

    def put(item: Any) -> bool:
        while not stop.is_set():
            try:
                handoff.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def parse() -> None:
        try:
            for item in chunks:
                if not put(item):
                    return
            put(done)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller, raised there
            put(exc)

    worker = threading.Thread(target=parse, name="plan-parse", daemon=True)
    worker.start()
    try:
        while True:
            item = handoff.get()
            if item is done:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        worker.join()


def _plan_chunks(chunks: ToolpathChunks | _Whole, cell: Any, opt: PlanOptions, progress: Progress | None, *,
                 meta: dict[str, Any], on_program: ProgramReady | None, sink: ProgramSink,
                 parse_s: float = 0.0, on_times: TimesSoFar | None = None) -> PlanResult:
    """Plan chunk by chunk into ``sink``, then finish the whole program: reach, cold extrusion, cycle time."""
    t0, parse_before = time.perf_counter(), parse_s     # parse_before: a whole toolpath's, parsed before
    deferred: FabricError | None = None
    try:
        stated = chunks.material()
    except FabricError as err:          # raised once the whole file is read: the parser's own errors come first
        stated, deferred = Material(), err
    material = resolve_material(stated, opt.filament_diameter_mm)    # the E -> volume factor, said aloud
    opt = dataclasses.replace(opt, filament_diameter_mm=material.filament_diameter_mm)
    mono = _Progress(progress)
    streamed = isinstance(chunks, ToolpathChunks)
    # a streamed chunk (at most ik_block_rows toolpath rows) is solved in one IK call: a call costs ~45 ms
    # before its first row (the rotation search), so a tail block of a few rows would cost as much
    ik_rows = opt.ik_block_rows * 5 // 4 if streamed else opt.ik_block_rows
    seed = Seed(np.asarray(cell.home_q_rad, dtype=float))
    reach, tot = Reach(), Totals()
    ik_s = refine_s = 0.0
    wobj = np.asarray(cell.wobj_T() if opt.wobj_T is None else opt.wobj_T, dtype=float)
    it = _parsed_ahead(chunks) if streamed else iter(chunks)
    prev_axis: np.ndarray | None = None          # the nozzle axis the chunk before ended with (multi-axis)
    prev_row: PrevRow | None = None              # the row the chunk before ended with (refine.py)
    reach_mm = reach_bound_mm(cell.robot)
    try:
        first = True
        while True:
            t = time.perf_counter()
            item = next(it, None)
            parse_s += time.perf_counter() - t
            if item is None:
                break
            tp, last = item
            split = split_turns(tp, opt.max_turn_deg, prev_axis)     # multi-axis: big nozzle turns in pieces
            if tp.axis is not None and len(tp):
                prev_axis = tp.axis[-1].copy()
            prog, asm = _assemble(split, cell, opt, first, last)
            del split
            t1 = time.perf_counter()
            status, rot = solve_chunk(prog, cell, dataclasses.replace(opt, ik_block_rows=ik_rows), None, seed, last,
                                 asm.axis)
            ik_s += time.perf_counter() - t1
            t1 = time.perf_counter()
            # moves whose joint interpolation would stray from the straight line are split (refine.py)
            ref = refine_linear(prog, status, rot, cell.robot, opt.linear_tol_mm, np.radians(JUMP_DEG), prev_row,
                                reach_mm)
            prog, status, rot = ref.program, ref.status, ref.rot_deg
            tot.split_rows += ref.added
            if len(prog):
                prev_row = PrevRow(prog.xyz_mm[-1].copy(), prog.quat_wxyz[-1].copy(), prog.q_rad[-1].copy(),
                                   int(status[-1]))
            refine_s += time.perf_counter() - t1
            _joint_speeds(prog, cell, asm.approach_speed_mm_s)
            motion = prog.op <= MOVEL
            if last:
                motion[-1] = False               # the home move is not an IK target
            envelope = envelope_status(prog.xyz_mm, motion, cell.plate_size_mm)     # over the plate, not below it
            rep = Reachability.from_status(status, rot, motion, prog.gcode_line, envelope, opt.allow_off_plate)
            rep.by_joint = joints_at_fault(prog.q_rad, status, motion, cell.robot.lower_rad, cell.robot.upper_rad)
            reach.add(rep, motion, sink.n)
            tot.add(prog, tp, asm, first)
            sink.append({**prog.columns(), "status": rep.status, "rot_deg": rep.rot_deg})
            del prog, tp, status, rot, rep, envelope, motion
            first = False
            mono(0.85 * chunks.fraction)
        summary = chunks.summary
        assert summary is not None                  # the chunks are through
        if deferred is not None:
            chunks.material(summary.n_lines)        # the error again, naming its line now that the lines are known
            raise deferred
        prog_meta: dict[str, Any] = {"source_lines": summary.n_lines, "slicer": chunks.slicer}
        if chunks.multiaxis:                     # the twin lays beads along each row's nozzle axis
            prog_meta.update(multiaxis=True, **_stated_width(getattr(chunks, "head", b"")))
        prog_meta.update(travel_lifts=tot.lifts, fan_events_dropped=tot.fan_events,
                         approach_speed_mm_s=tot.approach_speed_mm_s, leading_travels_dropped=tot.leading_dropped,
                         linear_split_rows=tot.split_rows)
        prog_meta.update(print_rows=tot.print_rows, options=opt.to_dict(), **material.meta(), **meta)
        prog, extra = sink.finish(wobj, prog_meta)
    except BaseException:
        if isinstance(sink, FileSink):
            sink.discard()
        raise
    finally:
        if isinstance(it, Generator):
            it.close()                          # the parser's worker stops (at once if it is done already)
    report = reach.report(extra["status"], extra["rot_deg"])
    report.cold = first_cold_extrusion(prog)     # the nozzle's set points against the material's minimum
    prog.release_pages()
    mono(0.85)
    if on_program is not None:               # the program is final: the estimate below only reads it
        on_program(prog, report)
    t2 = time.perf_counter()
    estimate = float("nan")
    slowed_rows = slowed_joint = t_end = None
    if report.reachable:
        from fabric.motion.timing import StartState, program_times
        start = StartState.at_joints(cell.robot, prog.wobj, np.asarray(cell.home_q_rad, dtype=float))
        out = sink.column("t_end_s", "f8", len(prog))
        timed = None
        if on_times is not None:
            on_times(out, 0)
            timed = lambda rows: on_times(out, rows)      # noqa: E731
        times = program_times(prog, cell.robot, 1.0, start, block_rows=opt.ik_block_rows, out=out,
                              progress=mono.sub(0.85, 1.0), timed=timed)
        estimate, t_end = times.total_s, times.t_end_s
        slowed_rows, slowed_joint = times.slowed_rows, times.slowed_joint
        prog.release_pages()
    timing_s = time.perf_counter() - t2
    mono(1.0)
    stats = PlanStats(
        moves=tot.moves, rows=len(prog), targets=tot.targets, layers=summary.n_layers,
        extruded_volume_mm3=tot.volume_mm3, path_length_mm=tot.path_mm, print_length_mm=tot.print_mm,
        travel_lifts=tot.lifts, fan_events_dropped=tot.fan_events, gcode_lines=summary.n_lines,
        unknown_commands=dict(summary.unknown_commands), slicer=chunks.slicer, material=material,
        warnings=list(material.warnings) + _floating(tot), split_rows=tot.split_rows, parse_s=parse_s, ik_s=ik_s,
        refine_s=refine_s, timing_s=timing_s,
        total_s=parse_before + time.perf_counter() - t0)
    return PlanResult(program=prog, report=report, estimate_s=estimate, stats=stats,
                      toolpath=chunks.toolpath, slowed_rows=slowed_rows, slowed_joint=slowed_joint, t_end_s=t_end)


def _floating(tot: Totals) -> list[str]:
    """The warning of a first layer laid well above the plate, if it is (``envelope.floating_warning``)."""
    warning = floating_warning(tot.first_layer_z_mm, tot.second_layer_z_mm)
    return [warning] if warning else []
