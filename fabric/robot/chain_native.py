"""The chain walk and the sag check of linear moves in C (``fabric/native/chain.c``).

:class:`fabric.robot.chain_point.ChainPoint` hands its walk here, and ``fabric.planning.refine`` its first
pass over every row of a program (the bound from the joint travel, then the TCP half-way through the
moves the bound does not clear). Each function answers None where there is no helper (no compiler, or
``FABRIC_NATIVE=0``): numpy's path then runs.
"""
from __future__ import annotations

import ctypes
from collections.abc import Sequence
from typing import Any

import numpy as np

from fabric import native

__all__ = ["Packed", "points", "straying", "available", "SIGNATURES"]

MAX_JOINTS = 16                 # chain.c's MAX_JOINTS
_L, _I = ctypes.c_long, ctypes.c_int
_F8 = native.array(np.float64)
_U1 = native.array(np.uint8)
_WALK = [native.array(np.int32, ndim=2), native.array(np.float64, ndim=2), native.array(np.float64, ndim=2),
         native.array(np.float64, ndim=1)]             # Packed.args: axes and signs, rotations, translations, TCP
SIGNATURES: dict[str, native.Signature] = {
    "chain_point": (_I, [_L, _I, *_WALK, native.array(np.float64, ndim=2, strided=True), _L,
                         native.array(np.float64, out=True)]),
    "chain_straying": (_L, [_L, _I, *_WALK, _F8, _U1, _U1, _F8, _F8, _F8, ctypes.c_double,
                            native.array(np.float64, nullable=True), _F8, _I, _I, _I,
                            native.array(np.int64, out=True), native.array(np.float64, out=True)]),
}


def _chain() -> ctypes.CDLL | None:
    return native.bound("chain", SIGNATURES)


def available() -> bool:
    return _chain() is not None


class Packed:
    """A chain walk's joints as the C side reads them: axes and their signs (2, nq) int32, rotations (nq, 9),
    translations (nq, 3), and the TCP (3,). ``joints``: each with ``axis`` (0-2), ``sign`` (+-1), ``R`` (3, 3)
    and ``t_mm`` (3,), from the base towards the TCP (``fabric.robot.chain_point.ChainPoint``'s)."""

    def __init__(self, joints: Sequence[Any], tcp_mm: np.ndarray) -> None:
        self.nq = len(joints)
        self.axis = np.ascontiguousarray([[jt.axis for jt in joints], [jt.sign for jt in joints]], dtype=np.int32)
        self.R = np.ascontiguousarray([np.asarray(jt.R, dtype=float).ravel() for jt in joints])
        self.t = np.ascontiguousarray([jt.t_mm for jt in joints], dtype=float)
        self.tcp = np.ascontiguousarray(tcp_mm, dtype=float)

    def args(self) -> tuple:
        return self.nq, self.axis, self.R, self.t, self.tcp


def points(walk: Packed, q_rad: np.ndarray) -> np.ndarray | None:
    """The walk's TCP positions (N, 3) mm for joints (N, nq); None without the helper."""
    lib = _chain()
    if lib is None:
        return None
    q = np.asarray(q_rad, dtype=float)
    if q.ndim != 2 or q.shape[1] != walk.nq:
        raise ValueError(f"joints of shape {q.shape} for a chain of {walk.nq}")
    if q.strides[1] != q.itemsize:
        q = np.ascontiguousarray(q)
    out = np.empty((len(q), 3))
    if q.strides[0] % q.itemsize or q.strides[0] < 0:
        q = np.ascontiguousarray(q)
    if lib.chain_point(len(q), *walk.args(), q, q.strides[0] // q.itemsize, out) < 0:
        raise ValueError(f"a chain of {walk.nq} joints is more than the helper takes ({MAX_JOINTS})")
    return out


def straying(walk: Packed, q_rad: np.ndarray, op: np.ndarray, status: np.ndarray, xyz_mm: np.ndarray,
             wobj: np.ndarray, reach_mm: np.ndarray, thresh_mm: float, prev_q_rad: np.ndarray | None,
             prev_xyz_mm: np.ndarray | None, prev_ok: bool, movel: int, ik_ok: int
             ) -> tuple[np.ndarray, np.ndarray] | None:
    """The rows of a program whose joint interpolation from the row before puts the TCP half-way more than
    ``thresh_mm`` from the middle of the straight line, and by how much (``chain.c``'s ``chain_straying``);
    None without the helper."""
    lib = _chain()
    if lib is None:
        return None
    n = len(q_rad)
    q, xyz = np.ascontiguousarray(q_rad, dtype=float), np.ascontiguousarray(xyz_mm, dtype=float)
    op, status = np.ascontiguousarray(op, dtype=np.uint8), np.ascontiguousarray(status, dtype=np.uint8)
    W, reach = np.ascontiguousarray(wobj, dtype=float), np.ascontiguousarray(reach_mm, dtype=float)
    pq = None if prev_q_rad is None else np.ascontiguousarray(prev_q_rad, dtype=float)
    px = np.ascontiguousarray(prev_xyz_mm if prev_xyz_mm is not None else np.zeros(3), dtype=float)
    rows, sag = np.empty(n, dtype=np.int64), np.empty(n)
    nq = walk.nq
    if q.shape != (n, nq) or op.shape != (n,) or status.shape != (n,) or xyz.shape != (n, 3) \
            or W.shape != (4, 4) or reach.shape != (nq,) or px.shape != (3,) or (pq is not None and pq.shape != (nq,)):
        raise ValueError("straying: the program's columns, the work object or the row before do not match")
    found = lib.chain_straying(n, *walk.args(), q, op, status, xyz, W, reach, float(thresh_mm), pq, px,
                               int(prev_ok), int(movel), int(ik_ok), rows, sag)
    if found < 0:
        raise ValueError(f"a chain of {walk.nq} joints is more than the helper takes ({MAX_JOINTS})")
    return rows[:found].copy(), sag[:found].copy()
