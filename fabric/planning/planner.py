"""The planner: G-code -> verified joint program (approach, print, return home) with its report.

Pipeline: parse (streamed in blocks) -> map the toolpath to Print rows in the
plate frame (:mod:`fabric.planning.mapping`) -> frame the print with an
*Approach* (a joint move from home to ``approach_height_mm`` above the first
point, then a linear move down, at the cell's approach speed, fine zones) and a
*Return home* (a linear move up, a joint move to the home joints) -> inverse
kinematics of every motion row with the free rotation about the nozzle axis
(``fabric.robot.path_ik.solve_path``), solved in blocks of ``ik_block_rows``
seeded with the previous block's last joints so memory stays bounded and
progress can be reported -> the cycle time from the motion model the station
executes (``fabric.motion.timing.time_program``).

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
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from fabric.gcode import Toolpath, parse_gcode, parse_gcode_file
from fabric.motion.cold import first_cold_extrusion
from fabric.motion.program import APPROACH, MOVEJ, MOVEL, PRINT, RETURN_HOME, SET_TEMP, WAIT, WAIT_TEMP, Program
from fabric.planning.envelope import envelope_status
from fabric.planning.mapping import map_toolpath
from fabric.planning.material import resolve_material
from fabric.planning.options import PlanOptions
from fabric.planning.post.names import program_name
from fabric.planning.report import PlanResult, PlanStats, Reachability
from fabric.robot.frames import inv_T, quat_from_R
from fabric.robot.kinematics import IK_JUMP, IK_OK

__all__ = ["plan_gcode", "plan_gcode_file", "plan_toolpath"]

Progress = Callable[[float], None]
ProgramReady = Callable[[Program, Reachability], None]     # told the program (and its reach) once it is final
JUMP_DEG = 45.0          # joint step between consecutive linear targets flagged as a jump


def _sub(progress: Progress | None, a: float, b: float) -> Progress | None:
    """A progress callback mapping [0, 1] onto [a, b] of ``progress``."""
    if progress is None:
        return None
    return lambda f: progress(a + (b - a) * min(max(f, 0.0), 1.0))


def plan_gcode(text: str | bytes | os.PathLike[str], cell: Any, options: PlanOptions | None = None,
               progress: Progress | None = None, filename: str | None = None,
               on_program: ProgramReady | None = None) -> PlanResult:
    """Plan G-code held in memory, or in a file named by a path, for ``cell`` (a :class:`fabric.robot.cell.Cell`).

    ``filename`` (optional) names the job: the program's ``meta`` gets
    ``filename`` and ``name`` (its stem), which exports use. ``on_program`` is
    called with the program as soon as it is final, before the cycle-time
    estimate, with its reachability (e.g. to start encoding or exporting it on another thread); it must
    not change either.
    """
    parse = parse_gcode_file if isinstance(text, os.PathLike) else parse_gcode     # a path: read in blocks
    return _parse_and_plan(parse, text, cell, options, progress, filename, on_program)


def _parse_and_plan(parse: Callable[..., Toolpath], source: Any, cell: Any, options: PlanOptions | None,
                    progress: Progress | None, filename: str | os.PathLike[str] | None,
                    on_program: ProgramReady | None = None) -> PlanResult:
    """Parse (first quarter of the progress), plan the rest, name the program after ``filename``."""
    opt = options or PlanOptions()
    t0 = time.perf_counter()
    tp = parse(source, chord_tol_mm=opt.chord_tol_mm, progress=_sub(progress, 0.0, 0.25))
    meta = {"filename": Path(filename).name, "name": program_name(Path(filename).stem)} if filename else {}
    return plan_toolpath(tp, cell, opt, _sub(progress, 0.25, 1.0), parse_s=time.perf_counter() - t0, meta=meta,
                         on_program=on_program)


def plan_gcode_file(path: str | os.PathLike[str], cell: Any, options: PlanOptions | None = None,
                    progress: Progress | None = None) -> PlanResult:
    """Plan a G-code file, streaming it in blocks."""
    return _parse_and_plan(parse_gcode_file, path, cell, options, progress, path)


def _assemble(tp: Toolpath, cell: Any, opt: PlanOptions) -> tuple[Program, int]:
    """Program rows (plate frame, no joints yet); returns the program and its print-row count."""
    pr = map_toolpath(tp, opt, head=2, tail=2)
    h = opt.approach_height_mm or float(cell.approach_height_mm)
    v_app = min(opt.approach_speed_mm_s or float(cell.approach_speed_mm_s), opt.max_tcp_speed_mm_s)
    up = np.array([0.0, 0.0, h])
    n = len(pr.op)
    cols = {name: getattr(pr, name) for name in ("op", "xyz_mm", "speed_mm_s", "zone_mm", "flow_mm3_mm",
                                                 "value", "aux", "gcode_line", "layer")}
    section = np.full(n, PRINT, np.uint8)
    section[:2] = APPROACH
    section[-2:] = RETURN_HOME
    quat = np.zeros((n, 4))
    quat[:, 0] = 1.0
    prog = Program(**cols, section=section, q_rad=np.zeros((n, int(cell.robot.nq))), quat_wxyz=quat,
                   vel_r=np.zeros(n),
                   wobj=np.asarray(cell.wobj_T() if opt.wobj_T is None else opt.wobj_T, dtype=float),
                   meta={"source_lines": tp.n_lines, "slicer": tp.slicer})
    last = prog.xyz_mm[pr.stop - 1] if len(pr) else pr.first_xyz_mm
    prog.op[:2] = (MOVEJ, MOVEL)
    prog.op[-2:] = (MOVEL, MOVEJ)
    prog.xyz_mm[0], prog.xyz_mm[1] = pr.first_xyz_mm + up, pr.first_xyz_mm
    prog.xyz_mm[-2] = last + up
    prog.speed_mm_s[[0, 1, -2, -1]] = v_app
    prog.zone_mm[[0, 1, -2, -1]] = 0.0
    prog.gcode_line[1] = pr.first_line
    prog, dropped, dropped_lifts = _start_at_first_bead(prog, pr.stop)
    n = len(prog)
    # non-motion rows (temperatures, waits, retractions) hold the TCP where the last motion row left it
    motion = prog.op <= MOVEL
    last_motion = np.maximum.accumulate(np.where(motion, np.arange(n), 0))
    rest = np.flatnonzero(~motion)
    prog.xyz_mm[rest] = prog.xyz_mm[last_motion[rest]]
    prog.meta.update(travel_lifts=pr.n_lifts - dropped_lifts, fan_events_dropped=pr.n_fan_events,
                     approach_speed_mm_s=v_app, leading_travels_dropped=dropped)
    return prog, len(pr) - dropped


def _start_at_first_bead(prog: Program, stop: int) -> tuple[Program, int, int]:
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
        return prog, 0, 0
    lead = np.arange(2, int(extruding[0]))
    travel = lead[prog.op[lead] <= MOVEL]
    heat = lead[np.isin(prog.op[lead], (WAIT, SET_TEMP, WAIT_TEMP))]
    other = lead[(prog.op[lead] > MOVEL) & ~np.isin(prog.op[lead], (WAIT, SET_TEMP, WAIT_TEMP))]
    if len(travel):
        prog.xyz_mm[0] = prog.xyz_mm[travel[-1]] + (prog.xyz_mm[0] - prog.xyz_mm[1])
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
    return Program(**cols, wobj=prog.wobj, meta=prog.meta), k, lifts


def _solve(prog: Program, cell: Any, opt: PlanOptions, progress: Progress | None) -> tuple[np.ndarray, np.ndarray]:
    """IK of every motion row but the final home move, in blocks; fills q and quat. Returns (status, rot_deg)."""
    from fabric.robot.path_ik import solve_path

    robot = cell.robot
    wobj = prog.wobj
    home = np.asarray(cell.home_q_rad, dtype=float)
    n = len(prog)
    motion = np.flatnonzero(prog.op[:-1] <= MOVEL)
    axis_b = wobj[:3, :3] @ opt.nozzle_axis()
    status = np.zeros(n, np.uint8)
    rot = np.zeros(n)
    seed = home
    q_wobj_inv = quat_from_R(wobj[:3, :3].T)
    plate_is_base = bool(np.array_equal(wobj[:3, :3], np.eye(3)))     # a shifted plate: no rotation to apply
    block = opt.ik_block_rows
    for a in range(0, len(motion), block):
        idx = motion[a:a + block]
        put = _putter(idx)
        p = prog.xyz_mm[idx]
        if plate_is_base:
            xyz_b = p + wobj[:3, 3]
        else:
            xyz_b = np.einsum("ij,kj->ik", p, wobj[:3, :3]) + wobj[:3, 3]     # no BLAS: (N,3)x(3,3)
        res = solve_path(robot, xyz_b, np.broadcast_to(axis_b, xyz_b.shape), seed,
                         rot_range_deg=opt.rot_range_deg, rot_step_deg=opt.rot_step_deg, jump_deg=JUMP_DEG)
        put(prog.q_rad, res.q_rad)
        st = res.status.copy()
        if a > 0 and len(st) and st[0] == IK_OK and np.max(np.abs(res.q_rad[0] - seed)) > np.radians(JUMP_DEG):
            st[0] = IK_JUMP                      # across the block boundary, as solve_path does inside
        put(prog.quat_wxyz, res.quat_wxyz if plate_is_base else _quat_in_plate(q_wobj_inv, res.quat_wxyz))
        put(status, st)
        put(rot, res.rot_deg)
        good = np.flatnonzero(st == IK_OK)
        if len(good):
            seed = res.q_rad[good[-1]]
        if progress is not None:
            progress(min(a + block, len(motion)) / max(len(motion), 1))
    # the final joint move goes to the home joints
    prog.q_rad[-1] = home
    T_home = inv_T(wobj) @ robot.fk(home[None])[0]
    prog.xyz_mm[-1] = T_home[:3, 3]
    prog.quat_wxyz[-1] = quat_from_R(T_home[:3, :3])
    # non-motion rows repeat the previous row's pose and status
    is_m = prog.op <= MOVEL
    fill = np.where(is_m, np.arange(n), -1)
    np.maximum.accumulate(fill, out=fill)
    fill = np.maximum(fill, 0)
    rest = np.flatnonzero(~is_m)
    for name in ("q_rad", "quat_wxyz", "xyz_mm"):
        arr = getattr(prog, name)
        arr[rest] = arr[fill[rest]]
    status[rest], rot[rest] = status[fill[rest]], rot[fill[rest]]
    return status, rot


def _putter(idx: np.ndarray) -> Callable[[np.ndarray, np.ndarray], None]:
    """``put(dst, src)`` doing ``dst[idx] = src`` for sorted ``idx``: by slices when ``idx`` is a
    few long runs of consecutive rows (motion rows between rare events), else by fancy indexing."""
    cut = np.flatnonzero(np.diff(idx) != 1) + 1
    scattered = len(cut) >= 64 + len(idx) // 4096
    starts = [] if scattered else np.concatenate([[0], cut]).tolist()
    # no runs at all when idx is empty (starts is [0] then, the other two lists empty)
    runs = list(zip(starts, idx[starts].tolist() if len(idx) else [], np.diff(starts + [len(idx)]).tolist(),
                    strict=False))

    def put(dst: np.ndarray, src: np.ndarray) -> None:
        if scattered:
            dst[idx] = src
            return
        for k, row, m in runs:
            dst[row:row + m] = src[k:k + m]
    return put


def _quat_in_plate(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """``qa * qb`` (Hamilton product, (4,) by (N, 4)), sign fixed to w >= 0: base-frame TCP
    orientations expressed in the plate frame when ``qa`` is the inverse of the plate's."""
    w1, x1, y1, z1 = qa
    w2, x2, y2, z2 = qb[:, 0], qb[:, 1], qb[:, 2], qb[:, 3]
    q = np.empty_like(qb)
    q[:, 0] = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
    q[:, 1] = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
    q[:, 2] = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
    q[:, 3] = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
    q[q[:, 0] < 0] *= -1.0
    return q


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
    """Plan an interpreted toolpath for ``cell`` (see the module docstring).

    ``meta`` is added to the program's; ``on_program`` gets the program once it is final (see :func:`plan_gcode`).
    """
    opt = options or PlanOptions()
    t0 = time.perf_counter()
    material = resolve_material(tp.material, opt.filament_diameter_mm)    # the E -> volume factor, said aloud
    opt = dataclasses.replace(opt, filament_diameter_mm=material.filament_diameter_mm)
    prog, n_print = _assemble(tp, cell, opt)
    if progress is not None:
        progress(0.05)
    t1 = time.perf_counter()
    status, rot = _solve(prog, cell, opt, _sub(progress, 0.05, 0.85))
    ik_s = time.perf_counter() - t1
    _joint_speeds(prog, cell, float(prog.meta["approach_speed_mm_s"]))
    motion = prog.op <= MOVEL
    motion[-1] = False                       # the home move is not an IK target
    envelope = envelope_status(prog.xyz_mm, motion, cell.plate_size_mm)     # over the plate, not below it
    report = Reachability.from_status(status, rot, motion, prog.gcode_line, envelope, opt.allow_off_plate)
    prog.meta.update(print_rows=n_print, options=opt.to_dict(), **material.meta(), **(meta or {}))
    report.cold = first_cold_extrusion(prog)     # the nozzle's set points against the material's minimum
    if on_program is not None:               # the program is final: the estimate below only reads it
        on_program(prog, report)
    t2 = time.perf_counter()
    estimate = float("nan")
    slowed_rows = slowed_joint = t_end = None
    if report.reachable:
        from fabric.motion.timing import StartState, time_program
        start = StartState.at_joints(cell.robot, prog.wobj, np.asarray(cell.home_q_rad, dtype=float))
        timeline = time_program(prog, cell.robot, 1.0, start_state=start)
        estimate = float(timeline.total_s)
        slowed_rows, slowed_joint = timeline.slowed_rows, timeline.slowed_joint
        t_end = timeline.t_end_s
    timing_s = time.perf_counter() - t2
    if progress is not None:
        progress(1.0)
    step = np.zeros_like(prog.xyz_mm)
    np.subtract(prog.xyz_mm[1:], prog.xyz_mm[:-1], out=step[1:])
    d = np.sqrt(np.einsum("ij,ij->i", step, step))
    del step
    pm = (prog.section == PRINT) & (prog.op == MOVEL)
    lin = prog.op == MOVEL
    stats = PlanStats(
        moves=len(tp), rows=len(prog), targets=int((prog.op <= MOVEL).sum()), layers=tp.n_layers,
        extruded_volume_mm3=float(np.dot(prog.flow_mm3_mm[lin], d[lin])), path_length_mm=float(d[pm].sum()),
        print_length_mm=float(d[pm & (prog.flow_mm3_mm > 0)].sum()),
        travel_lifts=int(prog.meta["travel_lifts"]), fan_events_dropped=int(prog.meta["fan_events_dropped"]),
        gcode_lines=tp.n_lines, unknown_commands=dict(tp.unknown_commands), slicer=tp.slicer, material=material,
        warnings=list(material.warnings),
        parse_s=parse_s, ik_s=ik_s, timing_s=timing_s, total_s=parse_s + time.perf_counter() - t0)
    return PlanResult(program=prog, report=report, estimate_s=estimate, stats=stats, toolpath=tp,
                      slowed_rows=slowed_rows, slowed_joint=slowed_joint, t_end_s=t_end)
