"""The path IK's branch tracking in C for 6-axis OPW and UR arms (``fabric/native/armik.c``).

:meth:`fabric.robot.closed_form.ClosedFormIK.ik_cols` hands its rows here first: the C helper runs
``ClosedFormIK._track`` (the family's closed form, tracking and the full 8-branch method, the same state
machine) row by row, where numpy makes a dozen passes over memory per step. Its joints are numpy's to
the last bits of the trigonometric functions. Where it cannot answer (no helper: no compiler, or
``FABRIC_NATIVE=0``; another family: the Panda type, the reference arm; a row whose A1 is undefined and
held) :meth:`NativeTrack.track` says so and numpy's path runs.
"""
from __future__ import annotations

import ctypes
from typing import Any

import numpy as np

from fabric import native
from fabric.robot.kinematics import _LIMIT_TOL_RAD, ELBOW_SING_COS, SHOULDER_SING_MM, WRIST_SING_SIN

__all__ = ["NativeTrack"]

FAMILIES = {"opw": 0, "ur": 1}      # armik.c's FAMILY_*
_LENGTHS = 10                       # armik.c: the family's lengths take par[0:10]
_HOLD = -1                          # armik.c's ARMIK_HOLD

_lib: list[ctypes.CDLL | None] = []


def _armik() -> ctypes.CDLL | None:
    if not _lib:
        lib = native.library("armik")
        if lib is not None:
            f = lib.armik_track
            f.restype = ctypes.c_long
            f.argtypes = [ctypes.c_int, ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p,
                          ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
            lib.armik_par_count.restype = ctypes.c_long
        _lib.append(lib)
    return _lib[0]


def _lengths(arm: Any) -> list[float]:
    """The family's lengths in armik.c's order (``opw_branch``, ``ur_branch``)."""
    if arm.family == "opw":
        return [arm.a1, arm.a2, arm.b, arm.c1, arm.c2, arm.c3, arm.c4, arm.k, arm.phi]
    return [arm.d1, arm.a2, arm.a3, arm.d4, arm.d5, arm.d6]


class NativeTrack:
    """The C tracking of one 6-axis arm within its limits (see module docstring)."""

    def __init__(self, lib: ctypes.CDLL, arm: Any, lower_rad: np.ndarray, upper_rad: np.ndarray,
                 multi: np.ndarray) -> None:
        self._lib = lib
        self._arm = arm
        self._family = FAMILIES[arm.family]
        lengths = _lengths(arm)
        par = np.zeros(int(lib.armik_par_count()))
        par[:len(lengths)] = lengths
        k = _LENGTHS
        for block in (arm.off, arm.sign, lower_rad, upper_rad, np.asarray(multi, dtype=float)):
            par[k:k + 6] = block
            k += 6
        par[k:k + 4] = (WRIST_SING_SIN, ELBOW_SING_COS, SHOULDER_SING_MM, _LIMIT_TOL_RAD)
        self._par = par

    @classmethod
    def of(cls, arm: Any, lower_rad: np.ndarray, upper_rad: np.ndarray, multi: np.ndarray) -> NativeTrack | None:
        """The C tracking of ``arm``, or None where there is none (another family, no helper)."""
        if getattr(arm, "family", None) not in FAMILIES or arm.nq != 6:
            return None
        lib = _armik()
        return None if lib is None else cls(lib, arm, lower_rad, upper_rad, multi)

    def track(self, C: np.ndarray, seed: np.ndarray, max_rows: int, q: np.ndarray, row_ok: np.ndarray,
              reach_any: np.ndarray, sing: np.ndarray) -> bool:
        """``ClosedFormIK._track`` of end-frame columns ``C`` (9, N) from ``seed`` into ``q`` (6, N) and the
        three (N,) bool arrays; False (nothing written) where a row's A1 is undefined: numpy's path holds it."""
        n = C.shape[1]
        Cm = np.ascontiguousarray(self._arm._model_cols(C), dtype=float)
        seed = np.ascontiguousarray(seed, dtype=float)
        for a in (q, row_ok, reach_any, sing):
            assert a.flags.c_contiguous and a.shape[-1] == n and a.itemsize == (8 if a is q else 1)
        got = self._lib.armik_track(self._family, self._par.ctypes.data, n, Cm.ctypes.data, seed.ctypes.data,
                                    int(max_rows), q.ctypes.data, row_ok.ctypes.data, reach_any.ctypes.data,
                                    sing.ctypes.data)
        if got == _HOLD:
            return False
        if got != n:
            raise RuntimeError(f"armik_track answered {got} for {n} rows")
        return True
