"""Exact motion timing of a robot program: Ruckig joint moves and look-ahead linear moves.

This is the one motion model of the fabric: the planner's cycle-time estimate
and the twin's execution both call :func:`time_program`, so the estimate *is*
the executed schedule.

**Joint moves (MOVEJ)** are Ruckig jerk-limited state-to-state trajectories
(offline ``Ruckig.calculate``, no intermediate waypoints) from the previous
row's joints to the row's joints, starting and ending at rest (a fine point),
within the joint velocity limits scaled by ``vel_r * speed_r`` (capped at 1)
and the full acceleration and jerk limits. Their duration is Ruckig's exact
duration.

**Linear moves (MOVEL)** follow Klipper-style look-ahead on the TCP path in
the plate frame with one acceleration limit (:mod:`fabric.motion.lookahead`).

**Other rows**: WAIT lasts ``value`` seconds; WAIT_TEMP lasts until the
heater is within tolerance (closed form, :mod:`fabric.motion.thermal`);
SET_TEMP is instantaneous; RETRACT moves only the filament, ``|value| /
retract_speed_mm_s`` seconds with the robot at rest. A zero-length MOVEL that
only turns the tool takes ``max_j |dq_j| / vlim_j`` at rest.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Trajectory

from fabric.motion.lookahead import EPS_MM, LinearProfiles, PathSteps, linear_profiles
from fabric.motion.program import MOVEJ, MOVEL, RETRACT, SET_TEMP, WAIT, WAIT_TEMP, Program
from fabric.motion.thermal import Thermal
from fabric.motion.timeline import Timeline
from fabric.robot.frames import inv_T, quat_from_R
from fabric.wire.errors import ValidationError

__all__ = ["StartState", "time_program", "program_times", "ProgramTimes", "stop_timeline", "DEFAULT_ACCEL_MM_S2",
           "DEFAULT_RETRACT_SPEED_MM_S"]

DEFAULT_ACCEL_MM_S2 = 2000.0
DEFAULT_RETRACT_SPEED_MM_S = 35.0


@dataclass
class StartState:
    """Where a timed run begins: the robot's joints and TCP (plate frame), how far along the
    first row it already is (``s_mm``) and how fast it moves (``v_mm_s``, linear moves only),
    the heaters, and the absolute time ``t0_s`` the heaters' closed forms are anchored to."""

    q_rad: np.ndarray
    xyz_mm: np.ndarray
    quat_wxyz: np.ndarray
    s_mm: float = 0.0
    v_mm_s: float = 0.0
    thermal: Thermal | None = None
    t0_s: float = 0.0

    @classmethod
    def at_joints(cls, robot: Any, wobj: np.ndarray, q_rad: np.ndarray, thermal: Thermal | None = None,
                  t0_s: float = 0.0) -> StartState:
        """At rest at joints ``q_rad`` (TCP from forward kinematics, in the plate frame ``wobj``)."""
        q = np.asarray(q_rad, dtype=float).reshape(-1)
        Tp = inv_T(np.asarray(wobj, dtype=float)) @ np.asarray(robot.fk(q[None]))[0]
        return cls(q, Tp[:3, 3].copy(), quat_from_R(Tp[:3, :3]), thermal=thermal, t0_s=t0_s)


def time_program(program: Program, robot: Any, speed_r: float = 1.0, start_row: int = 0,
                 start_state: StartState | None = None, *, accel_mm_s2: float = DEFAULT_ACCEL_MM_S2,
                 flow_r: float = 1.0, retract_speed_mm_s: float = DEFAULT_RETRACT_SPEED_MM_S) -> Timeline:
    """Time rows ``start_row ..`` of ``program`` exactly (see module docstring).

    ``start_state`` defaults to the robot at rest on the previous row's pose
    (row 0's own pose for ``start_row == 0``, which makes a leading MOVEJ take no
    time: pass :meth:`StartState.at_joints` with the real joints to time the approach).
    """
    n_all = len(program)
    if not 0 <= start_row < n_all:
        raise ValidationError(f"start row {start_row} outside the program's {n_all} rows", field="start_row")
    for name, val in (("speed_r", speed_r), ("accel_mm_s2", accel_mm_s2),
                      ("retract_speed_mm_s", retract_speed_mm_s)):
        if not np.isfinite(val) or val <= 0:
            raise ValidationError(f"{name} must be a positive number, got {val}", field=name)
    if start_state is None:
        k = max(start_row - 1, 0)
        start_state = StartState(program.q_rad[k].copy(), program.xyz_mm[k].copy(), program.quat_wxyz[k].copy())
    sl = slice(start_row, n_all)
    dur, path, prof, trajs, first_quat = _row_durations(program, robot, speed_r, start_row, start_state,
                                                        accel_mm_s2, retract_speed_mm_s)
    op, seg = path.op, prof.seg
    n = len(op)
    _thermal_pass(program, sl, op, dur, start_state)
    t_end = np.cumsum(dur)
    t_start = np.concatenate([[0.0], t_end[:-1]])
    del dur
    full = {}
    for name in ("v0", "vc", "v1", "t1", "tc", "t3"):        # per segment -> per row (0 elsewhere)
        full[name] = np.zeros(n)
        full[name][seg] = getattr(prof, name)
        setattr(prof, name, None)                           # drop each profile once it is placed
    return Timeline(program=program, robot=robot, start_row=start_row, t_start_s=t_start, t_end_s=t_end,
                    v0_mm_s=full["v0"], vc_mm_s=full["vc"], v1_mm_s=full["v1"], t1_s=full["t1"],
                    tc_s=full["tc"], t3_s=full["t3"], len_mm=np.where(op == MOVEL, np.maximum(path.D, 0.0), 0.0),
                    accel_mm_s2=float(accel_mm_s2), first_from_q_rad=path.q0.copy(),
                    first_from_xyz_mm=path.xyz0.copy(), first_from_quat_wxyz=first_quat.copy(),
                    s0_mm=path.s0_mm, speed_r=float(speed_r), flow_r=float(flow_r), joint_traj=trajs,
                    slowed_rows=start_row + prof.slowed, slowed_joint=prof.slowed_joint)


def _row_durations(program: Program, robot: Any, speed_r: float, start_row: int, start_state: StartState,
                   accel_mm_s2: float, retract_speed_mm_s: float
                   ) -> tuple[np.ndarray, PathSteps, LinearProfiles, dict[int, Trajectory], np.ndarray]:
    """Every row's duration from ``start_row`` on but the heater waits' (left 0: :func:`_thermal_pass`), with
    the path, the linear profiles, the joint moves and the orientation the first row starts from."""
    sl = slice(start_row, len(program))
    path, first_quat = _path_steps(program, start_row, start_state)
    op, q = path.op, path.q
    vlim = np.asarray(robot.vel_limit_rad_s, dtype=float)
    dur = np.zeros(len(op))
    prof = linear_profiles(path, vlim, speed_r, accel_mm_s2, float(start_state.v_mm_s))
    dur[prof.seg] = prof.t1 + prof.tc + prof.t3
    # a zero-length linear move that only turns the tool: at rest, as fast as the slowest joint allows
    turn = np.flatnonzero((op == MOVEL) & (path.D <= EPS_MM) & prof.reorient)
    q_from = np.where((turn > 0)[:, None], q[np.maximum(turn - 1, 0)], path.q0[None])
    dur[turn] = np.max(np.abs(q[turn] - q_from) / vlim, axis=1)
    value = program.value[sl]
    dur[op == WAIT] = np.maximum(value[op == WAIT], 0.0)
    dur[op == RETRACT] = np.abs(value[op == RETRACT]) / retract_speed_mm_s
    trajs = _joint_moves(program, sl, q, path.q0, robot, speed_r, start_row)
    for i, tr in trajs.items():
        dur[i] = tr.duration
    return dur, path, prof, trajs, first_quat


@dataclass
class ProgramTimes:
    """What a plan keeps of its timing: the cycle time, the time each row ends (from the start state) and
    the rows a joint velocity limit slowed, with the limiting joint (0-based)."""

    total_s: float
    t_end_s: np.ndarray
    slowed_rows: np.ndarray
    slowed_joint: np.ndarray


def program_times(program: Program, robot: Any, speed_r: float = 1.0, start_state: StartState | None = None, *,
                  block_rows: int = 1 << 18, out: np.ndarray | None = None,
                  accel_mm_s2: float = DEFAULT_ACCEL_MM_S2, retract_speed_mm_s: float = DEFAULT_RETRACT_SPEED_MM_S,
                  progress: Callable[[float], None] | None = None,
                  timed: Callable[[int], None] | None = None) -> ProgramTimes:
    """The times of :func:`time_program` from row 0, computed ``block_rows`` rows at a time (memory: a few
    blocks of rows, whatever the program's length; ``out``: where to write the times, e.g. a mapped file).

    A program of at most ``block_rows`` rows is timed by :func:`time_program` itself. A longer one is timed
    in windows: the rows of a block plus enough rows before and after it that the look-ahead cannot see
    past them (a junction's speed depends on the rows within ``v^2 / 2a`` of path, ``v`` the fastest
    programmed speed: further on, the acceleration limit bounds it whatever comes; a window's ends are
    stops, as far from the block as that). Heater waits and the clock run through the blocks in order.
    The result equals the whole program's timing up to rounding. ``timed(rows)`` is told after each block
    how many rows' times are in ``out`` (a reader may take them while the rest are computed).
    """
    n = len(program)
    if start_state is None:
        start_state = StartState(program.q_rad[0].copy(), program.xyz_mm[0].copy(), program.quat_wxyz[0].copy())
    if n <= block_rows:
        tl = time_program(program, robot, speed_r, 0, start_state, accel_mm_s2=accel_mm_s2,
                          retract_speed_mm_s=retract_speed_mm_s)
        t_end = tl.t_end_s
        if out is not None:
            out[:] = t_end
            t_end = out
        if timed is not None:
            timed(n)
        return ProgramTimes(float(tl.total_s), t_end, tl.slowed_rows, tl.slowed_joint)
    t_end = np.empty(n) if out is None else out
    thermal = start_state.thermal.copy() if start_state.thermal is not None else Thermal()
    clock, clock_moving, waited = 0.0, 0.0, 0.0      # end of the last block; the same without heater waits
    slowed_rows, slowed_joint = [], []
    for a in range(0, n, block_rows):
        b = min(a + block_rows, n)
        s, e = _window(program, a, b, speed_r, accel_mm_s2)
        if s == 0:
            ss = dataclasses.replace(start_state, thermal=None)
        else:                                        # at rest where the row before the window ends
            ss = StartState(program.q_rad[s - 1].copy(), program.xyz_mm[s - 1].copy(),
                            program.quat_wxyz[s - 1].copy())
        win = program.slice(s, e)
        dur_w, _path, prof, _trajs, _q = _row_durations(win, robot, speed_r, 0, ss, accel_mm_s2,
                                                        retract_speed_mm_s)
        dur = dur_w[a - s:b - s].copy()
        keep = (prof.slowed >= a - s) & (prof.slowed < b - s)
        slowed_rows.append(prof.slowed[keep] + s)
        slowed_joint.append(prof.slowed_joint[keep])
        del dur_w, _path, prof, _trajs, win
        op = program.op[a:b]
        # heater waits, in order through the blocks (as _thermal_pass over the whole program)
        moving = np.cumsum(dur)
        idx = np.flatnonzero((op == SET_TEMP) | (op == WAIT_TEMP))
        if len(idx):
            before = np.concatenate([[0.0], moving[:-1]]) + clock_moving
            value, aux = program.value[a:b], program.aux[a:b]
            for i in idx.tolist():
                t_abs = start_state.t0_s + before[i] + waited
                if op[i] == SET_TEMP:
                    thermal.set_target(int(aux[i]), float(value[i]), t_abs)
                else:
                    dur[i] = thermal.wait_s(int(aux[i]), t_abs)
                    waited += dur[i]
        clock_moving += float(moving[-1]) if len(moving) else 0.0
        dur[0] += clock
        np.cumsum(dur, out=t_end[a:b])
        clock = float(t_end[b - 1])
        program.release_pages(0, b)
        if timed is not None:
            timed(b)
        if progress is not None:
            progress(b / n)
    return ProgramTimes(clock, t_end, np.concatenate(slowed_rows).astype(np.intp),
                        np.concatenate(slowed_joint).astype(np.intp))


def _window(program: Program, a: int, b: int, speed_r: float, accel_mm_s2: float) -> tuple[int, int]:
    """The rows ``[s, e)`` to time so that the rows ``[a, b)`` come out as in the whole program: at least
    ``v^2 / 2a`` (+ 50 %, + 1 mm) of linear path on each side, ``v`` the fastest speed programmed there."""

    def reach(lo: int, hi: int) -> tuple[float, float]:
        # linear path of rows [lo, hi) (a row's step from the row before; row 0 has none), fastest speed there
        if hi <= lo:
            return 0.0, 0.0
        xyz = program.xyz_mm[max(lo - 1, 0):hi]
        step = np.sqrt(np.einsum("ij,ij->i", xyz[1:] - xyz[:-1], xyz[1:] - xyz[:-1]))
        if lo == 0:
            step = np.concatenate([[0.0], step])
        lin = program.op[lo:hi] == MOVEL
        return float(step[lin].sum()), float(np.max(program.speed_mm_s[lo:hi][lin], initial=0.0)) * speed_r

    n = len(program)
    _dist, v_block = reach(a, b)
    s, m = a, 256
    while s > 0:
        s = max(a - m, 0)
        dist, v = reach(s, a)
        need = 1.5 * max(v, v_block) ** 2 / (2.0 * accel_mm_s2) + 1.0
        if dist >= need:
            break
        m *= 2
    e, m = b, 256
    while e < n:
        e = min(b + m, n)
        dist, v = reach(b, e)
        need = 1.5 * max(v, v_block) ** 2 / (2.0 * accel_mm_s2) + 1.0
        if dist >= need:
            break
        m *= 2
    return s, e


def _path_steps(program: Program, start_row: int, ss: StartState) -> tuple[PathSteps, np.ndarray]:
    """The rows from ``start_row`` as TCP steps, and the orientation the first row starts from.

    A remainder resumed part-way along a linear row (``ss.s_mm > 0``) covers
    that row from the previous row's target, minus the ``s_mm`` already done;
    otherwise the first row starts from the start state's pose.
    """
    sl = slice(start_row, len(program))
    op = program.op[sl]
    partial = ss.s_mm > 0 and start_row > 0 and op[0] == MOVEL
    if partial:
        q0, xyz0 = program.q_rad[start_row - 1], program.xyz_mm[start_row - 1]
        first_quat = program.quat_wxyz[start_row - 1]
    else:
        q0, xyz0 = ss.q_rad, ss.xyz_mm
        first_quat = ss.quat_wxyz
    q0, xyz0 = np.asarray(q0, dtype=float), np.asarray(xyz0, dtype=float)
    xyz = program.xyz_mm[sl]
    d = np.stack([np.diff(xyz[:, k], prepend=xyz0[k]) for k in range(3)])    # (3, N) TCP steps, by column
    L = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    L[op != MOVEL] = 0.0
    s0 = float(np.clip(ss.s_mm, 0.0, L[0])) if partial else 0.0
    D = L.copy()
    D[0] -= s0
    path = PathSteps(op=op, q=program.q_rad[sl], q0=q0, d=d, L=L, D=D, speed_mm_s=program.speed_mm_s[sl],
                 zone_mm=program.zone_mm[sl], xyz0=xyz0, s0_mm=s0)
    return path, np.asarray(first_quat, dtype=float)


def _joint_moves(program: Program, sl: slice, q: np.ndarray, q0: np.ndarray, robot: Any, speed_r: float,
                 start_row: int) -> dict[int, Trajectory]:
    """Ruckig rest-to-rest trajectories of every MOVEJ row (keyed by local row index)."""
    idx = np.flatnonzero(program.op[sl] == MOVEJ)
    out: dict[int, Trajectory] = {}
    if not len(idx):
        return out
    dof = q.shape[1]
    otg = Ruckig(dof)
    inp = InputParameter(dof)
    vlim = np.asarray(robot.vel_limit_rad_s, dtype=float)
    inp.max_acceleration = np.asarray(robot.acc_limit_rad_s2, dtype=float).tolist()
    inp.max_jerk = np.asarray(robot.jerk_limit_rad_s3, dtype=float).tolist()
    vel_r = program.vel_r[sl]
    for i in idx.tolist():
        r = float(np.clip(vel_r[i] * speed_r, 1e-3, 1.0))
        inp.max_velocity = (vlim * r).tolist()
        inp.current_position = (q[i - 1] if i > 0 else q0).tolist()
        inp.target_position = q[i].tolist()
        traj = Trajectory(dof)
        res = otg.calculate(inp, traj)
        if res not in (Result.Working, Result.Finished):
            raise ValidationError(f"row {start_row + i}: joint move cannot be timed ({res})", field="q_rad",
                                  row=start_row + i, gcode_line=int(program.gcode_line[start_row + i]))
        out[i] = traj
    return out


def _thermal_pass(program: Program, sl: slice, op: np.ndarray, dur: np.ndarray, ss: StartState) -> None:
    """Apply set points in order and fill WAIT_TEMP durations from the closed-form heater model."""
    idx = np.flatnonzero((op == SET_TEMP) | (op == WAIT_TEMP))
    if not len(idx):
        return
    thermal = ss.thermal.copy() if ss.thermal is not None else Thermal()
    t_before = np.concatenate([[0.0], np.cumsum(dur)[:-1]])
    value, aux = program.value[sl], program.aux[sl]
    extra = 0.0
    for i in idx.tolist():
        t_abs = ss.t0_s + t_before[i] + extra
        if op[i] == SET_TEMP:
            thermal.set_target(int(aux[i]), float(value[i]), t_abs)
        else:
            dur[i] = thermal.wait_s(int(aux[i]), t_abs)
            extra += dur[i]


def stop_timeline(tl: Timeline, t_s: float) -> tuple[Timeline | None, int, float]:
    """A controlled stop from ``t_s`` (local) inside a linear move of ``tl``.

    The TCP keeps following the programmed path and slows at the acceleration
    limit from its current speed ``v`` to rest, over ``v^2 / (2 a)`` mm, crossing
    into following linear rows if needed. The look-ahead already guarantees this
    fits before the next stop point, and the slowing profile lies under the
    planned one, so no junction or cap is exceeded. Returns the stop leg (None
    when already at rest) and where it stops: ``(row, s_mm)`` with ``s_mm`` along
    that row, normalised to ``(row + 1, 0)`` when a row is finished exactly.
    """
    i = int(tl.locate(np.array([t_s]))[0])
    p = tl.program
    row = tl.start_row + i
    if p.op[row] != MOVEL:
        raise ValueError("stop_timeline needs a linear move")
    s_at, v_at = tl.profile(np.array([i]), np.array([t_s - tl.t_start_s[i]]))
    s_abs = float(s_at[0] + (tl.s0_mm if i == 0 else 0.0))
    v = float(v_at[0])
    a = tl.accel_mm_s2
    L_row = float(tl.row_length_mm(np.array([i]))[0])
    left = v * v / (2.0 * a)
    pieces: list[tuple[int, float, float, float]] = []   # (local row, covered mm, v0, v1)
    k, pos, v_now = i, s_abs, v
    stop_k, stop_pos = i, s_abs
    while left > 0.0 and k < tl.n:
        r = tl.start_row + k
        if p.op[r] not in (MOVEL, SET_TEMP):
            break
        Lk = float(tl.row_length_mm(np.array([k]))[0]) if p.op[r] == MOVEL else 0.0
        take = max(min(Lk - pos, left), 0.0)
        v_next = float(np.sqrt(max(v_now * v_now - 2.0 * a * take, 0.0))) if take < left else 0.0
        pieces.append((k, take, v_now, v_next))
        stop_k, stop_pos = k, pos + take
        left -= take
        v_now = v_next
        k, pos = k + 1, 0.0
    if not pieces:
        return (None, row + 1, 0.0) if s_abs >= L_row and L_row > 0 else (None, row, s_abs)
    stop_row, stop_s = tl.start_row + stop_k, stop_pos
    L_last = float(tl.row_length_mm(np.array([stop_k]))[0])
    if p.op[stop_row] != MOVEL or stop_pos >= L_last - EPS_MM:
        stop_row, stop_s = stop_row + 1, 0.0
    n = len(pieces)
    v0 = np.array([pc[2] for pc in pieces])
    v1 = np.array([pc[3] for pc in pieces])
    t3 = (v0 - v1) / a
    t_end = np.cumsum(t3)
    first = tl.start_row + i
    from_q, from_xyz, from_quat = tl.from_pose(np.array([i]))
    out = Timeline(program=p, robot=tl.robot, start_row=first, t_start_s=np.concatenate([[0.0], t_end[:-1]]),
                   t_end_s=t_end, v0_mm_s=v0, vc_mm_s=v0.copy(), v1_mm_s=v1, t1_s=np.zeros(n), tc_s=np.zeros(n),
                   t3_s=t3, len_mm=np.array([pc[1] for pc in pieces]), accel_mm_s2=a,
                   first_from_q_rad=from_q[0], first_from_xyz_mm=from_xyz[0], first_from_quat_wxyz=from_quat[0],
                   s0_mm=s_abs, speed_r=tl.speed_r, flow_r=tl.flow_r)
    return out, stop_row, stop_s
