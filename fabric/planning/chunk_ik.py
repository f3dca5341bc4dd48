"""Inverse kinematics of one chunk of the program: every motion row, block by block, seeded across chunks.

The rows of a chunk (plate frame) are turned into the robot base frame (``wobj_T @ p``, the nozzle axis
``R_wobj @ axis``) and solved by :func:`fabric.robot.path_ik.solve_path` in blocks of ``ik_block_rows``, each
from the last reachable joints before it (:class:`Seed`, carried to the next chunk): a first row that moves a
joint more than ``JUMP_DEG`` from them is a jump, as inside a block. The final home move of the last chunk gets
the home joints; rows that are not moves repeat the pose of the move before them.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from fabric.motion.program import MOVEL, Program
from fabric.planning.options import PlanOptions
from fabric.robot.frames import inv_T, quat_from_R, quat_sign
from fabric.robot.kinematics import IK_JUMP, IK_OK

__all__ = ["JUMP_DEG", "Seed", "solve_chunk", "putter", "quat_in_plate"]

JUMP_DEG = 45.0          # joint step between consecutive linear targets flagged as a jump


@dataclass
class Seed:
    """Where the IK of the next block starts: the last reachable joints so far (home before any), and whether a
    block was solved before (then its first row is tested for a jump from them)."""

    q_rad: np.ndarray
    solved: bool = False


def solve_chunk(prog: Program, cell: Any, opt: PlanOptions, progress: Callable[[float], None] | None,
                seed: Seed | None = None, last: bool = True, axis: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """IK of every motion row (but the final home move of the ``last`` chunk), in blocks, from ``seed`` (carried
    to the next chunk); fills q and quat. ``axis`` (rows, 3): each row's nozzle axis in the plate frame, from
    the tip up the nozzle (multi-axis G-code; the TCP z points the other way, out of the nozzle); None: the
    options' one nozzle axis. Returns (status, rot_deg)."""
    from fabric.robot.path_ik import solve_path

    robot = cell.robot
    wobj = prog.wobj
    home = np.asarray(cell.home_q_rad, dtype=float)
    if seed is None:
        seed = Seed(home)
    n = len(prog)
    motion = np.flatnonzero(prog.op[:-1] <= MOVEL) if last else np.flatnonzero(prog.op <= MOVEL)
    axis_b = wobj[:3, :3] @ opt.nozzle_axis()
    status = np.zeros(n, np.uint8)
    rot = np.zeros(n)
    q_wobj_inv = quat_from_R(wobj[:3, :3].T)
    plate_is_base = bool(np.array_equal(wobj[:3, :3], np.eye(3)))     # a shifted plate: no rotation to apply
    block = opt.ik_block_rows
    for a in range(0, len(motion), block):
        idx = motion[a:a + block]
        put = putter(idx)
        p = prog.xyz_mm[idx]
        if plate_is_base:
            xyz_b = p + wobj[:3, 3]
        else:
            xyz_b = np.einsum("ij,kj->ik", p, wobj[:3, :3]) + wobj[:3, 3]     # no BLAS: (N,3)x(3,3)
        if axis is None:
            z_b = np.broadcast_to(axis_b, xyz_b.shape)
        else:                                   # TCP z = -(nozzle axis), turned into the base frame
            z_b = -(axis[idx] if plate_is_base else np.einsum("ij,kj->ik", axis[idx], wobj[:3, :3]))
        res = solve_path(robot, xyz_b, z_b, seed.q_rad,
                         rot_range_deg=opt.rot_range_deg, rot_step_deg=opt.rot_step_deg, jump_deg=JUMP_DEG)
        put(prog.q_rad, res.q_rad)
        st = res.status.copy()
        if seed.solved and len(st) and st[0] == IK_OK and \
                np.max(np.abs(res.q_rad[0] - seed.q_rad)) > np.radians(JUMP_DEG):
            st[0] = IK_JUMP                      # across the block boundary, as solve_path does inside
        seed.solved = seed.solved or len(idx) > 0
        put(prog.quat_wxyz, res.quat_wxyz if plate_is_base else quat_in_plate(q_wobj_inv, res.quat_wxyz))
        put(status, st)
        put(rot, res.rot_deg)
        good = np.flatnonzero(st == IK_OK)
        if len(good):
            seed.q_rad = res.q_rad[good[-1]].copy()
        if progress is not None:
            progress(min(a + block, len(motion)) / max(len(motion), 1))
    if last:                                 # the final joint move goes to the home joints
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


def putter(idx: np.ndarray) -> Callable[[np.ndarray, np.ndarray], None]:
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


def quat_in_plate(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """``qa * qb`` (Hamilton product, (4,) by (N, 4)), signed by ``frames.quat_sign``: base-frame TCP
    orientations expressed in the plate frame when ``qa`` is the inverse of the plate's."""
    w1, x1, y1, z1 = qa
    w2, x2, y2, z2 = qb[:, 0], qb[:, 1], qb[:, 2], qb[:, 3]
    q = np.empty_like(qb)
    q[:, 0] = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
    q[:, 1] = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
    q[:, 2] = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
    q[:, 3] = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
    return quat_sign(q)
