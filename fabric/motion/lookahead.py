"""Look-ahead speed planning of linear moves: cruise caps, junction speeds, passes and trapezoids.

Linear moves (MOVEL) are planned like Klipper's look-ahead, on the TCP path in
the plate frame with one acceleration limit ``a``:

1. each row's cruise cap is ``speed_mm_s * speed_r``, lowered so that no joint
   exceeds its velocity limit: with joints interpolated linearly along the row
   a joint turns ``|dq_j|`` over the row length ``L``, so at TCP speed ``v`` it
   moves at ``v * |dq_j| / L``; the cap is ``min_j vlim_j * L / |dq_j|`` and
   rows where it bites are reported (``slowed`` / ``slowed_joint``);
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

Every step is its own function, so its temporaries are freed before the next
one runs (a million-row program keeps only a few arrays alive at a time).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabric.motion import lookahead_native
from fabric.motion.program import MOVEL, SET_TEMP

__all__ = ["EPS_MM", "LinearProfiles", "PathSteps", "linear_profiles"]

EPS_MM = 1e-9
use_native_caps = True            # False: numpy's caps (tests compare the two)


@dataclass
class PathSteps:
    """The rows being timed, as the look-ahead sees them.

    ``op``, ``q``: the rows' instruction codes and joint targets; ``q0``: the
    joints before the first row; ``d`` (3, N): TCP steps from the previous
    target, column by column; ``L``: full row lengths (0 for non-linear rows);
    ``D``: lengths still to cover (the first row may start ``s0_mm`` along its
    length, from TCP ``xyz0``); ``speed_mm_s``, ``zone_mm``: the programmed
    speeds and zones.
    """

    op: np.ndarray
    q: np.ndarray
    q0: np.ndarray
    d: np.ndarray
    L: np.ndarray
    D: np.ndarray
    speed_mm_s: np.ndarray
    zone_mm: np.ndarray
    xyz0: np.ndarray
    s0_mm: float = 0.0


@dataclass
class LinearProfiles:
    """Trapezoids of the linear segments: ``seg`` are their row indices; per segment the entry,
    cruise and exit speeds and the three phase durations; ``reorient`` marks every row whose joints
    move; ``slowed`` / ``slowed_joint`` the rows capped by a joint velocity limit and that joint."""

    seg: np.ndarray
    v0: np.ndarray
    vc: np.ndarray
    v1: np.ndarray
    t1: np.ndarray
    tc: np.ndarray
    t3: np.ndarray
    reorient: np.ndarray
    slowed: np.ndarray
    slowed_joint: np.ndarray


def linear_profiles(path: PathSteps, vlim: np.ndarray, speed_r: float, a: float, v_start: float) -> LinearProfiles:
    """Plan every linear row of ``path`` (steps 1-4 of the module docstring); ``v_start``: the TCP's
    speed when the first row begins (non-zero only for a remainder re-timed mid-move)."""
    segmask = (path.op == MOVEL) & (path.D > EPS_MM)
    seg = np.flatnonzero(segmask)
    cap, slow, worst, reorient = _caps(path.speed_mm_s[seg] * speed_r, path.q, path.q0, path.L[seg], seg, vlim)
    J, conn, forced = _junctions(path, seg, segmask, reorient, cap, a, v_start)
    u, ex = _passes(path.D[seg], J, conn, cap, a, forced, v_start)
    del J
    v0, vc, v1, t1, tc, t3 = _trapezoids(path.D[seg], u, ex, cap, a)
    return LinearProfiles(seg=seg, v0=v0, vc=vc, v1=v1, t1=t1, tc=tc, t3=t3, reorient=reorient,
                          slowed=seg[slow], slowed_joint=worst[slow])


def _caps(cap_prog: np.ndarray, q: np.ndarray, q0: np.ndarray, Ls: np.ndarray, seg: np.ndarray,
          vlim: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """1. Cruise caps: programmed speed and, joint by joint, the velocity limits (``|dq_j| / (vlim_j L)``
    is joint j's rad/s per mm/s of TCP speed). Returns caps, slowed mask and joint, moving-joint rows.
    In C where the helper is built (``lookahead_native.py``: the same caps, one pass over the rows)."""
    if use_native_caps:
        got = lookahead_native.caps(cap_prog, q, q0, Ls, seg, vlim)
        if got is not None:
            return got
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
    slowed = cap_joint < cap_prog * (1.0 - 1e-12)
    return np.minimum(cap_prog, cap_joint), slowed, worst, reorient


def _junctions(path: PathSteps, seg: np.ndarray, segmask: np.ndarray, reorient: np.ndarray, cap: np.ndarray,
               a: float, v_start: float) -> tuple[np.ndarray, np.ndarray, bool]:
    """2. Squared junction speeds into each segment, whether it is connected to the previous one
    (only transparent rows between), and whether the caller imposes the entry speed."""
    op, d, L, D, zone = path.op, path.d, path.L, path.D, path.zone_mm
    lin = op == MOVEL
    blocking = ~(segmask | (op == SET_TEMP) | (lin & ~reorient))
    cb = np.cumsum(blocking)
    cf = np.cumsum(lin & (D <= EPS_MM) & (zone <= 0))
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
        fine_between = cf[seg[1:] - 1] - cf[seg[:-1]] > 0      # a zero-length fine row between two segments
        z = np.where(fine_between, 0.0, zone[seg[:-1]])
        J[1:] = np.minimum(a * z * R, np.minimum(cap[:-1], cap[1:]) ** 2)
    J[~conn] = 0.0
    forced = bool(m > 0 and v_start > 0 and cb[seg[0]] == 0)
    return J, conn, forced


def _passes(Dseg: np.ndarray, J: np.ndarray, conn: np.ndarray, cap: np.ndarray, a: float, forced: bool,
            v_start: float) -> tuple[np.ndarray, np.ndarray]:
    """3. Backward and forward passes on squared speeds, as cumulative minima along the path.
    Returns the squared entry speed of each segment and its squared exit speed."""
    P = 2.0 * a * np.concatenate([[0.0], np.cumsum(Dseg)])
    T = np.minimum(J, cap ** 2) + P[:-1]
    end = np.ones(len(Dseg), dtype=bool)
    end[:-1] = ~conn[1:]
    T[end] = np.minimum(T[end], P[1:][end])
    w = np.minimum.accumulate(T[::-1])[::-1] - P[:-1]
    del T
    if forced:
        w[0] = v_start ** 2
    u = np.minimum.accumulate(w - P[:-1]) + P[:-1]
    del w
    if forced and len(Dseg):
        # the first chain starts at v_start: it may only slow down at the acceleration limit
        chain = np.cumsum(~conn) == np.cumsum(~conn)[0]
        chain[0] = True
        u = np.where(chain, np.maximum(u, v_start ** 2 - P[:-1]), u)
        u[0] = v_start ** 2
    u = np.maximum(u, 0.0)
    ex = np.zeros(len(Dseg))
    ex[:-1] = np.where(conn[1:], u[1:], 0.0)
    return u, ex


def _trapezoids(Dseg: np.ndarray, u: np.ndarray, ex: np.ndarray, cap: np.ndarray,
                a: float) -> tuple[np.ndarray, ...]:
    """4. Trapezoids (general: each phase may speed up or slow down): v0, vc, v1, t1, tc, t3."""
    v0, v1 = np.sqrt(u), np.sqrt(ex)
    peak = np.sqrt(0.5 * (u + ex) + a * Dseg)
    valley = np.sqrt(np.maximum(0.5 * (u + ex) - a * Dseg, 0.0))
    vc = np.where(cap >= np.maximum(v0, v1), np.minimum(cap, peak), np.maximum(cap, valley))
    del peak, valley
    t1 = np.abs(vc - v0) / a
    t3 = np.abs(v1 - vc) / a
    dc = np.maximum(Dseg - 0.5 * (v0 + vc) * t1 - 0.5 * (vc + v1) * t3, 0.0)
    tc = np.where(vc > 0, dc / np.where(vc > 0, vc, 1.0), 0.0)
    return v0, vc, v1, t1, tc, t3
