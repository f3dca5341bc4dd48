"""The closed-form solver's tracking step in C (``fabric/native/armtrack.c``) for OPW and UR arms.

:func:`tracker` answers a :class:`Tracker` for an arm of either family, or None
(another family, no C helper here, or ``FABRIC_NATIVE=0``): the solver then
takes its numpy path, which gives the same joints (a test holds them together).
A tracker solves one branch row by row from the previous row's joints and stops
at the first row that is unreachable, out of limits or not provably the nearest
branch; the solver's full method takes over there, as after numpy's block.
"""
from __future__ import annotations

import ctypes
from typing import Any

import numpy as np

from fabric import native

__all__ = ["Tracker", "tracker"]

_DOUBLES = ctypes.POINTER(ctypes.c_double)
_lib: list[ctypes.CDLL | None] = []


def _armtrack() -> ctypes.CDLL | None:
    if not _lib:
        lib = native.library("armtrack")
        if lib is not None:
            for name in ("opw_track", "ur_track"):
                f = getattr(lib, name)
                f.restype = ctypes.c_long
                f.argtypes = [ctypes.c_void_p, ctypes.c_long, ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p,
                              ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p]
        _lib.append(lib)
    return _lib[0]


class Tracker:
    """One family's C tracking step with the arm's parameters and joint limits packed once."""

    def __init__(self, fn: Any, params: np.ndarray, joints: np.ndarray) -> None:
        self._fn = fn
        self._params = params          # kept alive: C reads them on every call
        self._joints = joints

    def __call__(self, C: np.ndarray, i: int, j: int, branch: int, prev: np.ndarray, q: np.ndarray,
                 sing: np.ndarray) -> int:
        """Track ``branch`` over rows ``i:j`` of the columns ``C`` (9, N) from joints ``prev`` (6,); the rows
        kept go to ``q[:, i:]`` (6, N) and ``sing[i:]``; returns how many were kept (from row i on)."""
        assert C.dtype == np.float64 and C.flags.c_contiguous and q.flags.c_contiguous and q.dtype == np.float64
        assert sing.dtype == np.bool_ and sing.flags.c_contiguous
        prev = np.ascontiguousarray(prev, dtype=np.float64)
        off8 = 8 * i
        return int(self._fn(C.ctypes.data + off8, C.shape[1], j - i, self._params.ctypes.data,
                            self._joints.ctypes.data, int(branch), prev.ctypes.data, q.ctypes.data + off8,
                            q.shape[1], sing.ctypes.data + i))


def _joints_block(arm: Any, lower: np.ndarray, upper: np.ndarray, multi: np.ndarray) -> np.ndarray:
    """The C ``Joints`` block: offsets, signs, limits, single-turn mask, base frame (has_base, R, t)."""
    base = getattr(arm, "_base", None)
    B = np.eye(4) if base is None else np.asarray(base, dtype=float)
    parts = [arm.off, arm.sign, lower, upper, (~np.asarray(multi, dtype=bool)).astype(float),
             [0.0 if base is None else 1.0], B[:3, :3].reshape(-1), B[:3, 3]]
    return np.ascontiguousarray(np.concatenate([np.asarray(p, dtype=float).reshape(-1) for p in parts]))


def tracker(arm: Any, lower: np.ndarray, upper: np.ndarray, multi: np.ndarray) -> Tracker | None:
    """The C tracking step for ``arm`` (an ``OPWArm`` or ``URArm``), or None where there is none."""
    family = getattr(arm, "family", None)
    if family not in ("opw", "ur") or getattr(arm, "nq", 0) != 6:
        return None
    lib = _armtrack()
    if lib is None:
        return None
    if family == "opw":
        params = [arm.a1, arm.a2, arm.b, arm.c1, arm.c2, arm.c3, arm.c4, arm.k, arm.phi, np.cos(arm.phi),
                  np.sin(arm.phi)]
        fn = lib.opw_track
    else:
        params = [arm.d1, arm.a2, arm.a3, arm.d4, arm.d5, arm.d6]
        fn = lib.ur_track
    return Tracker(fn, np.ascontiguousarray(params, dtype=float), _joints_block(arm, lower, upper, multi))
