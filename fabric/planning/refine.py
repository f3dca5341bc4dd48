"""Linear moves split where interpolating the joints between two rows would leave the straight line.

A program row of a linear move (MOVEL) holds the joints at its end. Whoever
executes the program between two rows by interpolating the joints linearly
(the twin, the collision checker's sweep, a controller streamed the CSV's
joints) moves the TCP along a curve, not the straight line a controller's
MoveL/LIN/movel follows: it sags by about ``k L^2`` for a move of length
``L``. On a 40 mm line of the sample part the KR 6's nozzle dipped 0.3 mm,
through a first layer 0.3 mm above the plate, and the certified sweep
rightly reported the tip in the plate.

:func:`refine_linear` measures that sag and splits the moves where it exceeds
``tol_mm`` into equal pieces, each solved on the straight line, so that every
executor follows the straight line within ``tol_mm`` (the planner's
``linear_tol_mm``, 0.1 mm by default: about an industrial arm's own path
accuracy, and a first layer 0.2-0.3 mm over the plate keeps most of its
clearance; 0.05 mm costs a million-move raster of 5 mm moves a forward
kinematics per move, 0.1 mm one for one move in ten):

1. a bound from the joint travel and the arm's offsets alone (the
   bound of :func:`sag_bound_mm`) passes over most short moves of a print
   without computing anything else;
2. the others are measured: the TCP of the interpolated joints half-way
   against the middle of the straight line (forward kinematics, vectorised;
   the sag of a curve bent evenly is largest there), and a move is split
   when it strays more than ``SPLIT_R`` of ``tol_mm`` (the rest of the
   margin for a bend that is not even);
3. a move straying more than ``tol_mm`` becomes ``m = ceil(sqrt(sag / tol))``
   pieces (the sag falls with the square of the length); the new rows lie on
   the line, their orientation interpolated as the twin interpolates it
   (normalised quaternions), their joints the IK solution nearest the
   interpolated joints (all branches at once on a closed-form arm), marked
   ``IK_JUMP`` if that is more than ``jump_rad`` from them in any joint (the
   straight line needs a motion the two ends do not show). The pieces, and
   only they, are measured again, up to ``ROUNDS`` times.

A new row copies its move's row (operation, speed, flow per mm, zone,
G-code line, layer): the volume, the path and the G-code line of every point
stay as they were; only a fine zone (a stop) is kept at the move's end alone,
so a split move does not stop at its new rows.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fabric.motion.program import COLUMNS, MOVEL, Program
from fabric.robot import chain_native
from fabric.robot.frames import R_from_quat, make_T, nlerp_quat
from fabric.robot.kinematics import IK_JOINT_LIMIT, IK_JUMP, IK_OK, IK_OUT_OF_REACH, IK_SINGULAR, pose_cols, wrap_diff

__all__ = ["Refined", "PrevRow", "refine_linear", "sag_bound_mm", "reach_bound_mm"]

ROUNDS = 3                     # measure-and-split passes at most
MAX_PIECES = 256               # pieces of one move in one pass
PASS_ZONE_MM = 0.01            # the zone of a new row where its move's row is a fine one (0: a stop)
SPLIT_R = 0.8                  # a move is split when its measured sag exceeds this share of the tolerance


class PrevRow(NamedTuple):
    """The row before a chunk's first (the previous chunk's last): plate-frame TCP, joints, IK status."""

    xyz_mm: np.ndarray
    quat_wxyz: np.ndarray
    q_rad: np.ndarray
    status: int


class Refined(NamedTuple):
    """The program with its split moves, its rows' IK status and rotation, and how many rows were added."""

    program: Program
    status: np.ndarray
    rot_deg: np.ndarray
    added: int


def reach_bound_mm(robot) -> np.ndarray:
    """Upper bounds (nq,) in mm on the TCP's distance from each joint's axis, whatever the joints.

    With ``c_k`` a point on axis k (the one nearest axis k+1; on the last axis, the TCP's foot), ``c_k`` and
    ``c_k+1`` are both fixed in link k, so ``|c_k+1 - c_k|`` never changes; the TCP is at most
    ``D_k = |c_k+1 - c_k| + D_k+1`` from ``c_k`` (``D_n = |TCP - c_n|``) and at most
    ``dist(c_k+1, axis k) + D_k+1`` from axis k (the last axis: its own, constant distance). A spherical
    wrist's axes meet, an axial tool lies on the last axis: both count nothing. An arm with a joint that is
    not revolute gets the sum of every offset after each joint.
    """
    from fabric.robot.joint_axes import joint_axes, line_closest_points
    ax = joint_axes(robot.pin_model, robot.tcp_frame_id)
    tcp = ax.flange_T[:3, 3]
    P, U = ax.points_mm, ax.directions
    n = len(P)
    if not ax.revolute.all():
        m = robot.pin_model
        offsets = [float(np.linalg.norm(m.jointPlacements[j].translation)) for j in range(1, m.njoints)]
        last = float(np.linalg.norm(m.frames[robot.tcp_frame_id].placement.translation))
        return 1000.0 * np.cumsum((offsets[1:] + [last])[::-1])[::-1]

    def dist(x: np.ndarray, k: int) -> float:
        d = x - P[k]
        return float(np.linalg.norm(d - (d @ U[k]) * U[k]))

    c = [line_closest_points(P[k], U[k], P[k + 1], U[k + 1])[0] for k in range(n - 1)]
    c.append(P[-1] + ((tcp - P[-1]) @ U[-1]) * U[-1])
    far = np.empty(n)
    far[-1] = np.linalg.norm(tcp - c[-1])
    for k in range(n - 2, -1, -1):
        far[k] = np.linalg.norm(c[k + 1] - c[k]) + far[k + 1]
    reach = np.empty(n)
    reach[-1] = dist(tcp, n - 1)
    for k in range(n - 1):
        reach[k] = dist(c[k + 1], k) + far[k + 1]
    return reach


def sag_bound_mm(dq_rad: np.ndarray, reach_mm: np.ndarray) -> np.ndarray:
    """How far the TCP can stray from its chord over linear joint interpolations of travels ``dq_rad``
    ((N, nq) -> (N,)). Along the interpolation ``p'' = sum_jk dq_j dq_k z_j x (z_k x (p - o_k))`` (j <= k),
    whose terms are at most ``r_max(j,k)``, the TCP's distance from the later axis: ``|p''| <= sum_k r_k |dq_k|
    (|dq_k| + 2 sum_{j<k} |dq_j|)``, and a C2 curve strays at most ``max |p''| / 8`` from its chord."""
    d = np.abs(dq_rad)
    before = np.cumsum(d, axis=1) - d
    return (d * (d + 2.0 * before)) @ reach_mm / 8.0


def refine_linear(prog: Program, status: np.ndarray, rot_deg: np.ndarray, robot, tol_mm: float,
                  jump_rad: float, prev: PrevRow | None = None, reach_mm: np.ndarray | None = None) -> Refined:
    """Split the linear moves of ``prog`` whose joint interpolation strays more than ``tol_mm`` from the
    straight line (module docstring). ``prev``: the row before the first (a chunk after the first); row 0
    of a program without it has no move to split."""
    reach = reach_bound_mm(robot) if reach_mm is None else reach_mm
    added = 0
    look: np.ndarray | None = None              # the rows to look at (None: every row)
    for _ in range(ROUNDS):
        rows, sag = _straying(prog, status, robot, tol_mm, prev, reach, look)
        if not len(rows):
            break
        pieces = np.clip(np.ceil(np.sqrt(sag / (SPLIT_R * tol_mm))), 2, MAX_PIECES).astype(np.int64)
        prog, status, rot_deg, look = _split(prog, status, rot_deg, robot, rows, pieces, jump_rad, prev)
        added += int(np.sum(pieces - 1))
    return Refined(prog, status, rot_deg, added)


def _before(prog: Program, rows: np.ndarray, prev: PrevRow | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """TCP position, orientation and joints of the row before each of ``rows`` (sorted; row 0's is ``prev``,
    which a linear move in row 0 always has: a chunk after the first starts with one)."""
    i = np.maximum(rows - 1, 0)
    xyz, quat, q = prog.xyz_mm[i], prog.quat_wxyz[i], prog.q_rad[i]
    if len(rows) and rows[0] == 0:
        assert prev is not None
        xyz[0], quat[0], q[0] = prev.xyz_mm, prev.quat_wxyz, prev.q_rad
    return xyz, quat, q


def _straying(prog: Program, status: np.ndarray, robot, tol_mm: float, prev: PrevRow | None,
              reach_mm: np.ndarray, look: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The linear-move rows (of ``look``, sorted; None: all) whose joint interpolation strays more than
    ``SPLIT_R * tol_mm`` half-way, and by how much."""
    if len(prog) == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    if look is None:
        return _straying_all(prog, status, robot, tol_mm, prev, reach_mm)
    ok = status == IK_OK
    rows = look
    before_ok = np.where(rows > 0, ok[np.maximum(rows - 1, 0)], prev is not None and prev.status == IK_OK)
    cand = rows[(prog.op[rows] == MOVEL) & ok[rows] & before_ok]
    if not len(cand):
        return cand, np.zeros(0)
    q1 = prog.q_rad[cand]
    q0 = _before(prog, cand, prev)[2]
    keep = sag_bound_mm(q1 - q0, reach_mm) > SPLIT_R * tol_mm
    return _measured(prog, robot, cand[keep], q0[keep], q1[keep], tol_mm, prev)


def _straying_all(prog: Program, status: np.ndarray, robot, tol_mm: float, prev: PrevRow | None,
                  reach_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_straying` of every row: in C where the arm has a chain walk and the helper is built (one pass,
    a row at a time), else by slices of the whole program (no gathering of a million rows)."""
    prev_ok = prev is not None and prev.status == IK_OK
    walk = getattr(robot, "chain_point", None)
    if walk is not None and walk.use_native:
        got = chain_native.straying(walk.packed(), prog.q_rad, prog.op, status, prog.xyz_mm, prog.wobj, reach_mm,
                                    SPLIT_R * tol_mm, None if prev is None else prev.q_rad,
                                    None if prev is None else prev.xyz_mm, prev_ok, MOVEL, IK_OK)
        if got is not None:
            return got
    ok = status == IK_OK
    dq = np.empty_like(prog.q_rad)
    np.subtract(prog.q_rad[1:], prog.q_rad[:-1], out=dq[1:])
    dq[0] = prog.q_rad[0] - (prev.q_rad if prev is not None else prog.q_rad[0])
    before_ok = np.empty(len(prog), dtype=bool)
    before_ok[1:] = ok[:-1]
    before_ok[0] = prev_ok
    measure = (prog.op == MOVEL) & ok & before_ok
    measure &= sag_bound_mm(dq, reach_mm) > SPLIT_R * tol_mm
    cand = np.flatnonzero(measure)
    q1 = prog.q_rad[cand]
    return _measured(prog, robot, cand, q1 - dq[cand], q1, tol_mm, prev)


def _measured(prog: Program, robot, cand: np.ndarray, q0: np.ndarray, q1: np.ndarray, tol_mm: float,
              prev: PrevRow | None) -> tuple[np.ndarray, np.ndarray]:
    """Of the moves ``cand`` (joints ``q0`` -> ``q1``), those whose joints half-way put the TCP more than
    ``SPLIT_R * tol_mm`` from the middle of the line, and by how much."""
    if not len(cand):
        return cand, np.zeros(0)
    a = _before(prog, cand, prev)[0]
    w = prog.wobj
    mid = 0.5 * (a + prog.xyz_mm[cand]) @ w[:3, :3].T + w[:3, 3]         # base frame
    sag = np.linalg.norm(robot.tcp_xyz_mm(0.5 * (q0 + q1)) - mid, axis=1)
    far = sag > SPLIT_R * tol_mm
    return cand[far], sag[far]


def _split(prog: Program, status: np.ndarray, rot_deg: np.ndarray, robot, rows: np.ndarray, pieces: np.ndarray,
           jump_rad: float, prev: PrevRow | None) -> tuple[Program, np.ndarray, np.ndarray, np.ndarray]:
    """``prog`` with move ``rows[k]`` cut into ``pieces[k]`` (new rows before each, on the line); returns
    it, its status and rotation, and the rows of the pieces (the new rows and the moves' own)."""
    n = len(prog)
    new = pieces - 1
    counts = np.ones(n, dtype=np.int64)
    counts[rows] = pieces
    end = np.cumsum(counts) - 1                                      # where each old row now is
    cols = {name: _spread(getattr(prog, name), rows, new, end) for name in COLUMNS}   # each row copied
    out = Program(**cols, wobj=prog.wobj, meta=prog.meta)
    status, rot_deg = _spread(status, rows, new, end), _spread(rot_deg, rows, new, end)
    # the new rows: move k's pieces[k] - 1 of them, at s = 1/m .. (m-1)/m, right before the move's own row
    move = np.repeat(np.arange(len(rows)), new)
    step = np.arange(len(move)) - np.repeat(np.cumsum(new) - new, new) + 1          # 1 .. m-1 per move
    at = np.repeat(end[rows] - new, new) + step - 1                                   # their rows now
    f = step / np.repeat(pieces, new)
    xyz0, quat0, q0 = (v[move] for v in _before(prog, rows, prev))
    r = rows[move]
    out.xyz_mm[at] = xyz0 + f[:, None] * (prog.xyz_mm[r] - xyz0)
    quat = nlerp_quat(quat0, prog.quat_wxyz[r], f)                 # as the twin turns the tool between rows
    out.quat_wxyz[at] = quat
    q_lerp = q0 + f[:, None] * (prog.q_rad[r] - q0)
    q, st = _solve_near(robot, out.xyz_mm[at], quat, prog.wobj, q_lerp, jump_rad)
    out.q_rad[at] = q
    status[at] = st
    fine = out.zone_mm[at] <= 0
    out.zone_mm[at[fine]] = PASS_ZONE_MM
    return out, status, rot_deg, np.sort(np.concatenate([at, end[rows]]))


def _spread(col: np.ndarray, rows: np.ndarray, new: np.ndarray, end: np.ndarray) -> np.ndarray:
    """``col`` with ``new[k]`` copies of row ``rows[k]`` right before it (``rows`` ascending, ``end`` each old
    row's place in the result): ``np.repeat`` of the rows, by one copy per stretch of rows between two split
    moves (a few hundred stretches of a million rows: memory's speed, not a repeat's per row)."""
    if not len(rows):
        return col.copy()
    out = np.empty((int(end[-1]) + 1, *col.shape[1:]), dtype=col.dtype)
    bounds = [0, *rows.tolist(), len(col)]
    at, copies = end.take(bounds[:-1]).tolist(), [0, *new.tolist()]
    for k in range(len(bounds) - 1):
        a, b = bounds[k], bounds[k + 1]
        out[at[k] - copies[k]:at[k]] = col[a]
        out[at[k]:at[k] + b - a] = col[a:b]
    return out


def _solve_near(robot, xyz_plate: np.ndarray, quat_plate: np.ndarray, wobj: np.ndarray, q_lerp: np.ndarray,
                jump_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Joints (M, nq) and IK status (M,) of TCP poses (plate frame), each the solution nearest ``q_lerp``."""
    m = len(xyz_plate)
    T = wobj @ make_T(R_from_quat(quat_plate), xyz_plate)                  # base frame
    cf = robot.closed_form
    if cf is None:                          # a numeric solver: each pose seeded with its interpolated joints
        q = np.empty_like(q_lerp)
        st = np.empty(m, np.uint8)
        for i in range(m):
            qi, si = robot.ik(T[i:i + 1], q_lerp[i])
            q[i], st[i] = qi[0], si[0]
    else:
        free = None if cf.free_joint is None else q_lerp[:, cf.free_joint]
        qb, ok, reach, sing = cf.branches_cols(pose_cols(T, cf.tool_inv_T), None, free)
        d = qb - q_lerp[:, None, :]
        d[..., cf.multi] = wrap_diff(d[..., cf.multi])              # multi-turn joints: any turn
        dist = np.max(np.abs(d), axis=2)                             # (M, 8)
        allowed = np.where(ok.any(axis=1, keepdims=True), ok, reach)
        b = np.argmin(np.where(allowed, dist, np.inf), axis=1)
        r = np.arange(m)
        q = q_lerp + d[r, b]                                         # single-turn joints: qb itself
        st = np.full(m, IK_OK, np.uint8)
        st[sing[r, b]] = IK_SINGULAR
        st[~ok[r, b]] = IK_JOINT_LIMIT
        st[~reach.any(axis=1)] = IK_OUT_OF_REACH
        lo, hi = robot.lower_rad, robot.upper_rad
        st[(st == IK_OK) & np.any((q < lo - 1e-9) | (q > hi + 1e-9), axis=1)] = IK_JOINT_LIMIT
    st[(st == IK_OK) & (np.max(np.abs(q - q_lerp), axis=1) > jump_rad)] = IK_JUMP
    return q, st
