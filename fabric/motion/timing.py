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

**Linear moves (MOVEL)** are planned like Klipper's look-ahead, on the TCP
path in the plate frame with one acceleration limit ``accel_mm_s2``:

1. each row's cruise cap is ``speed_mm_s * speed_r``, lowered so that no joint
   exceeds its velocity limit: with joints interpolated linearly along the row
   a joint turns ``|dq_j|`` over the row length ``L``, so at TCP speed ``v`` it
   moves at ``v * |dq_j| / L``; the cap is ``min_j vlim_j * L / |dq_j|`` and
   rows where it bites are reported (``slowed_rows`` / ``slowed_joint``);
2. the junction between two consecutive linear moves allows
   ``v_j^2 = a * zone * sin(theta/2) / (1 - sin(theta/2))`` (junction
   deviation, ``theta`` the angle between the reversed incoming and the
   outgoing direction: pi on a straight line, 0 on a reversal), with the zone
   of the incoming row as the deviation; a fine zone (0) stops. Any row other
   than a linear move or a set-point change (MOVEJ, WAIT, WAIT_TEMP, RETRACT)
   is a stop on both sides; zero-length linear moves are transparent;
3. a backward pass ``w_i = min(M_i, w_{i+1} + 2 a L_i)`` (squared speeds) and a
   forward pass ``u_i = min(w_i, u_{i-1} + 2 a L_{i-1})`` give every junction's
   speed. Both are written as cumulative minima of ``speed^2 -+ 2 a s`` along
   the path (``np.minimum.accumulate``), which is exact across stop points
   (a zero-speed junction bounds everything beyond it), so a million moves
   time in a fraction of a second with no Python loop;
4. each row then gets a trapezoid (entry ``v0``, cruise ``vc``, exit ``v1``);
   when a re-timed remainder starts faster than its new cruise cap (a speed
   override lowered mid-print) the first rows decelerate at ``a`` instead.

**Other rows**: WAIT lasts ``value`` seconds; WAIT_TEMP lasts until the
heater is within tolerance (closed form, :mod:`fabric.motion.thermal`);
SET_TEMP is instantaneous; RETRACT moves only the filament, ``|value| /
retract_speed_mm_s`` seconds with the robot at rest. A zero-length MOVEL that
only turns the tool takes ``max_j |dq_j| / vlim_j`` at rest.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Trajectory

from fabric.errors import UnreachableError, ValidationError
from fabric.robot.frames import inv_T, quat_from_R
from fabric.motion.program import MOVEJ, MOVEL, RETRACT, SET_TEMP, WAIT, WAIT_TEMP, Program
from fabric.motion.thermal import Thermal
from fabric.motion.timeline import Timeline

__all__ = ["StartState", "time_program", "stop_timeline", "validate_program", "mini_program",
           "DEFAULT_ACCEL_MM_S2", "DEFAULT_RETRACT_SPEED_MM_S"]

DEFAULT_ACCEL_MM_S2 = 2000.0
DEFAULT_RETRACT_SPEED_MM_S = 35.0
_EPS_MM = 1e-9


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
                  t0_s: float = 0.0) -> "StartState":
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
    for name, val in (("speed_r", speed_r), ("accel_mm_s2", accel_mm_s2), ("retract_speed_mm_s", retract_speed_mm_s)):
        if not np.isfinite(val) or val <= 0:
            raise ValidationError(f"{name} must be a positive number, got {val}", field=name)
    k = max(start_row - 1, 0)
    ss = start_state or StartState(program.q_rad[k].copy(), program.xyz_mm[k].copy(), program.quat_wxyz[k].copy())
    sl = slice(start_row, n_all)
    op = program.op[sl]
    n = len(op)
    partial = ss.s_mm > 0 and start_row > 0 and op[0] == MOVEL
    src = (program.q_rad[start_row - 1], program.xyz_mm[start_row - 1]) if partial else (ss.q_rad, ss.xyz_mm)
    first_quat = program.quat_wxyz[start_row - 1] if partial else np.asarray(ss.quat_wxyz, dtype=float)
    q, xyz = program.q_rad[sl], program.xyz_mm[sl]
    q0, xyz0 = np.asarray(src[0], dtype=float), np.asarray(src[1], dtype=float)
    d = np.stack([np.diff(xyz[:, k], prepend=xyz0[k]) for k in range(3)])    # (3, N) TCP steps, by column
    L = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    L[op != MOVEL] = 0.0
    s0 = float(np.clip(ss.s_mm, 0.0, L[0])) if partial else 0.0
    D = L.copy()
    D[0] -= s0
    vlim = np.asarray(robot.vel_limit_rad_s, dtype=float)
    dur = np.zeros(n)
    prof = _linear_profiles(program, sl, (op, q, q0, d, L), D, vlim, speed_r, accel_mm_s2, float(ss.v_mm_s))
    seg = prof["seg"]
    dur[seg] = prof["t1"] + prof["tc"] + prof["t3"]
    turn = np.flatnonzero((op == MOVEL) & (D <= _EPS_MM) & prof["reorient"])
    q_from = np.where((turn > 0)[:, None], q[np.maximum(turn - 1, 0)], q0[None])      # previous row's joints
    dur[turn] = np.max(np.abs(q[turn] - q_from) / vlim, axis=1)
    value = program.value[sl]
    dur[op == WAIT] = np.maximum(value[op == WAIT], 0.0)
    dur[op == RETRACT] = np.abs(value[op == RETRACT]) / retract_speed_mm_s
    trajs = _joint_moves(program, sl, q, q0, robot, speed_r, start_row)
    for i, tr in trajs.items():
        dur[i] = tr.duration
    _thermal_pass(program, sl, op, dur, ss)
    t_end = np.cumsum(dur)
    t_start = np.concatenate([[0.0], t_end[:-1]])
    del dur
    full = {k: np.zeros(n) for k in ("v0", "vc", "v1", "t1", "tc", "t3")}
    for k in full:
        full[k][seg] = prof.pop(k)                             # drop each profile once it is placed
    return Timeline(program=program, robot=robot, start_row=start_row, t_start_s=t_start, t_end_s=t_end,
                    v0_mm_s=full["v0"], vc_mm_s=full["vc"], v1_mm_s=full["v1"], t1_s=full["t1"],
                    tc_s=full["tc"], t3_s=full["t3"], len_mm=np.where(op == MOVEL, np.maximum(D, 0.0), 0.0),
                    accel_mm_s2=float(accel_mm_s2), first_from_q_rad=q0.copy(),
                    first_from_xyz_mm=xyz0.copy(), first_from_quat_wxyz=np.asarray(first_quat, float).copy(),
                    s0_mm=s0, speed_r=float(speed_r), flow_r=float(flow_r), joint_traj=trajs,
                    slowed_rows=start_row + prof["slowed"], slowed_joint=prof["slowed_joint"])


def _linear_profiles(program: Program, sl: slice, rows: tuple[np.ndarray, ...], D: np.ndarray, vlim: np.ndarray,
                     speed_r: float, a: float, v_start: float) -> dict[str, np.ndarray]:
    """Caps, junction speeds, look-ahead passes and trapezoids of every linear row (vectorised; each
    step its own function, so its temporaries are freed before the next). ``rows``: op, q, q0, d, L."""
    op, q, q0, d, L = rows
    segmask = (op == MOVEL) & (D > _EPS_MM)
    seg = np.flatnonzero(segmask)
    cap, slow, worst, reorient = _caps(program.speed_mm_s[sl][seg] * speed_r, q, q0, L[seg], seg, vlim)
    J, conn, forced = _junctions(op, d, L, D, seg, segmask, reorient, program.zone_mm[sl], cap, a, v_start)
    Dseg = D[seg]
    # 3. look-ahead passes on squared speeds, as cumulative minima along the path
    P = 2.0 * a * np.concatenate([[0.0], np.cumsum(Dseg)])
    T = np.minimum(J, cap ** 2) + P[:-1]
    end = np.ones(len(seg), dtype=bool)
    end[:-1] = ~conn[1:]
    T[end] = np.minimum(T[end], P[1:][end])
    w = np.minimum.accumulate(T[::-1])[::-1] - P[:-1]
    del T, J
    if forced:
        w[0] = v_start ** 2
    u = np.minimum.accumulate(w - P[:-1]) + P[:-1]
    del w
    if forced and len(seg):
        chain = np.cumsum(~conn) == np.cumsum(~conn)[0]
        chain[0] = True
        u = np.where(chain, np.maximum(u, v_start ** 2 - P[:-1]), u)
        u[0] = v_start ** 2
    u = np.maximum(u, 0.0)
    ex = np.zeros(len(seg))
    ex[:-1] = np.where(conn[1:], u[1:], 0.0)
    # 4. trapezoids (general: each phase may speed up or slow down)
    v0, v1 = np.sqrt(u), np.sqrt(ex)
    peak = np.sqrt(0.5 * (u + ex) + a * Dseg)
    valley = np.sqrt(np.maximum(0.5 * (u + ex) - a * Dseg, 0.0))
    del u, ex
    vc = np.where(cap >= np.maximum(v0, v1), np.minimum(cap, peak), np.maximum(cap, valley))
    del peak, valley, cap
    t1 = np.abs(vc - v0) / a
    t3 = np.abs(v1 - vc) / a
    dc = np.maximum(Dseg - 0.5 * (v0 + vc) * t1 - 0.5 * (vc + v1) * t3, 0.0)
    tc = np.where(vc > 0, dc / np.where(vc > 0, vc, 1.0), 0.0)
    return {"seg": seg, "v0": v0, "vc": vc, "v1": v1, "t1": t1, "tc": tc, "t3": t3, "reorient": reorient,
            "slowed": seg[slow], "slowed_joint": worst[slow]}


def _caps(cap_prog: np.ndarray, q: np.ndarray, q0: np.ndarray, Ls: np.ndarray, seg: np.ndarray,
          vlim: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """1. Cruise caps: programmed speed and, joint by joint, the velocity limits (``|dq_j| / (vlim_j L)``
    is joint j's rad/s per mm/s of TCP speed). Returns caps, slowed mask and joint, moving-joint rows."""
    reorient = np.zeros(len(q), dtype=bool)
    worst = np.zeros(len(seg), dtype=np.intp)
    top = np.full(len(seg), -np.inf)
    for j in range(q.shape[1]):
        dq = np.abs(np.diff(q[:, j], prepend=q0[j]))
        reorient |= dq > 1e-12
        rate = dq[seg] / (vlim[j] * Ls)
        better = rate > top
        worst[better] = j
        top[better] = rate[better]
    cap_joint = 1.0 / np.maximum(top, 1e-300)
    return np.minimum(cap_prog, cap_joint), cap_joint < cap_prog * (1.0 - 1e-12), worst, reorient


def _junctions(op: np.ndarray, d: np.ndarray, L: np.ndarray, D: np.ndarray, seg: np.ndarray,
               segmask: np.ndarray, reorient: np.ndarray, zone: np.ndarray, cap: np.ndarray, a: float,
               v_start: float) -> tuple[np.ndarray, np.ndarray, bool]:
    """2. Squared junction speeds into each segment, whether it is connected to the previous one
    (only transparent rows between), and whether the caller imposes the entry speed."""
    lin = op == MOVEL
    blocking = ~(segmask | (op == SET_TEMP) | (lin & ~reorient))
    cb = np.cumsum(blocking)
    cf = np.cumsum(lin & (D <= _EPS_MM) & (zone <= 0))
    m = len(seg)
    conn = np.zeros(m, dtype=bool)
    J = np.zeros(m)
    if m > 1:
        conn[1:] = cb[seg[1:] - 1] - cb[seg[:-1]] == 0
        Ls = L[seg]
        u = [d[k][seg] / Ls for k in range(3)]                  # unit directions, column by column
        cos_j = -(u[0][:-1] * u[0][1:] + u[1][:-1] * u[1][1:] + u[2][:-1] * u[2][1:])
        del u, Ls
        sin_h = np.sqrt(np.clip(0.5 * (1.0 - cos_j), 0.0, 1.0))
        R = sin_h / np.maximum(1.0 - sin_h, 1e-12)
        z = np.where(cf[seg[1:] - 1] - cf[seg[:-1]] > 0, 0.0, zone[seg[:-1]])
        J[1:] = np.minimum(a * z * R, np.minimum(cap[:-1], cap[1:]) ** 2)
    J[~conn] = 0.0
    return J, conn, bool(m > 0 and v_start > 0 and cb[seg[0]] == 0)


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
    s, v = tl.profile(np.array([i]), np.array([t_s - tl.t_start_s[i]]))
    s_abs = float(s[0] + (tl.s0_mm if i == 0 else 0.0))
    v = float(v[0])
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
    if p.op[stop_row] != MOVEL or stop_pos >= L_last - _EPS_MM:
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


def validate_program(program: Program, robot: Any, *, max_temp_c: tuple[float, float] = (300.0, 120.0)) -> None:
    """Check a program before it runs: shapes and op codes, finite values, sane speeds, zones,
    flows, waits and set points (ValidationError), and every row's joints inside the robot's
    limits (UnreachableError naming the row, G-code line, joint and limit)."""
    if not isinstance(program, Program):
        raise ValidationError(f"expected a Program, got {type(program).__name__}", field="program")
    n = len(program)
    if n == 0:
        raise ValidationError("the program has no rows", field="program")
    op = program.op

    def bad(mask: np.ndarray, field_name: str, what: str) -> None:
        if mask.any():
            r = int(np.flatnonzero(mask)[0])
            g = int(program.gcode_line[r])
            raise ValidationError(f"row {r} (G-code line {g}): {field_name} {what}", field=field_name, row=r,
                                  gcode_line=g)

    bad(op > RETRACT, "op", "is not a known instruction")
    for name in ("q_rad", "xyz_mm", "quat_wxyz", "speed_mm_s", "vel_r", "zone_mm", "flow_mm3_mm", "value"):
        arr = getattr(program, name)
        bad(~np.isfinite(arr).reshape(n, -1).all(axis=1), name, "is not finite")
    if program.q_rad.shape[1] != len(np.asarray(robot.lower_rad)):
        raise ValidationError(f"program has {program.q_rad.shape[1]} joints, robot has {len(robot.lower_rad)}",
                              field="q_rad")
    bad(np.linalg.norm(program.quat_wxyz, axis=1) < 1e-6, "quat_wxyz", "is not a rotation")
    bad((op == MOVEL) & (program.speed_mm_s <= 0), "speed_mm_s", "must be > 0 on a linear move")
    bad((op == MOVEJ) & ((program.vel_r <= 0) | (program.vel_r > 1)), "vel_r", "must be in (0, 1] on a joint move")
    bad(program.zone_mm < 0, "zone_mm", "must be >= 0")
    bad(program.flow_mm3_mm < 0, "flow_mm3_mm", "must be >= 0")
    bad((op == WAIT) & (program.value < 0), "value", "(wait seconds) must be >= 0")
    temp = (op == SET_TEMP) | (op == WAIT_TEMP)
    bad(temp & ((program.aux < 0) | (program.aux > 1)), "aux", "(heater id) must be 0 (nozzle) or 1 (bed)")
    hi = np.where(program.aux == 1, max_temp_c[1], max_temp_c[0])
    bad(temp & ((program.value < 0) | (program.value > hi)), "value", "(set point) out of range")
    lo_l, up_l = np.asarray(robot.lower_rad, float), np.asarray(robot.upper_rad, float)
    out = (program.q_rad < lo_l - 1e-9) | (program.q_rad > up_l + 1e-9)
    if out.any():
        r, j = (int(v) for v in np.argwhere(out)[0])
        g = int(program.gcode_line[r])
        val = float(program.q_rad[r, j])
        lim = float(lo_l[j] if val < lo_l[j] else up_l[j])
        raise UnreachableError(f"row {r} (G-code line {g}): joint A{j + 1} at {np.degrees(val):.3f} deg is outside "
                               f"its limit {np.degrees(lim):.3f} deg", row=r, gcode_line=g, joint=j,
                               value_deg=float(np.degrees(val)), limit_deg=float(np.degrees(lim)),
                               reason="joint limit")


def mini_program(rows: list[dict[str, Any]], wobj: np.ndarray) -> Program:
    """A small program from explicit rows (column name -> value; others as ``Program.empty``):
    the twin's own moves (lift, lower, retract, home) are timed by the same model."""
    p = Program.empty(len(rows))
    p.wobj = np.asarray(wobj, dtype=float).reshape(4, 4)
    for i, row in enumerate(rows):
        for name, val in row.items():
            getattr(p, name)[i] = val
    return p
