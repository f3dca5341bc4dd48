"""The path IK's branch tracking in C for OPW, UR and Panda-type arms (``fabric/native/armik.c``).

:meth:`fabric.robot.closed_form.ClosedFormIK.ik_cols` hands its rows here first: the C helper runs
``ClosedFormIK._track`` (the family's closed form, tracking and the full 8-branch method, the same state
machine) row by row, where numpy makes a dozen passes over memory per step. Its joints are numpy's to
the last bits of the trigonometric functions. Where it cannot answer (no helper: no compiler, or
``FABRIC_NATIVE=0``; another family: the reference arm of the tests; a row whose A1 is undefined and held)
:meth:`NativeTrack.track` says so and numpy's path runs. A Panda-type arm's A7 (its redundancy parameter) is
given per row or once, as numpy's path takes it; its cosine and sine are numpy's too.
"""
from __future__ import annotations

import ctypes
from typing import Any

import numpy as np

from fabric import native
from fabric.robot.kinematics import ELBOW_SING_COS, LIMIT_TOL_RAD, SHOULDER_SING_MM, WRIST_SING_SIN, wrap

__all__ = ["NativeTrack", "available", "SIGNATURES"]

FAMILIES = {"opw": 0, "ur": 1, "panda": 2}      # armik.c's FAMILY_*
_NQ_MAX = 7                         # armik.c's NQ_MAX: par holds 7 values per joint block
_HOLD = -1                          # armik.c's ARMIK_HOLD

_L, _I, _D = ctypes.c_long, ctypes.c_int, ctypes.c_double
_F8 = native.array(np.float64, ndim=1)
_F8_OUT = native.array(np.float64, out=True)
_B1_OUT = native.array(np.bool_, ndim=1, out=True)
SIGNATURES: dict[str, native.Signature] = {
    # family, nq, constants, parameters, n, C (9, n), A7's cos, sin and value, per row, seed, max_rows; out: q,
    # row_ok, reach_any, singular
    "armik_track": (_L, [_I, _I, _F8, _F8, _L, native.array(np.float64, ndim=2), _F8, _F8, _F8, _I, _F8, _L,
                         native.array(np.float64, ndim=2, out=True), _B1_OUT, _B1_OUT, _B1_OUT]),
    "armik_place_multi_turn": (None, [_L, native.array(np.float64, ndim=1, out=True), _D, _D, _D, _D, _F8_OUT]),
    "armik_par_count": (ctypes.c_long, []),
    "armik_panda_count": (ctypes.c_long, []),
}


def _armik() -> ctypes.CDLL | None:
    return native.bound("armik", SIGNATURES)


def available() -> bool:
    """Whether the C helper is built and loaded here (else numpy's path answers every family)."""
    return _armik() is not None


class NativeTrack:
    """The C tracking of one arm (OPW, UR or Panda type) within its limits (see module docstring)."""

    def __init__(self, lib: ctypes.CDLL, arm: Any, lower_rad: np.ndarray, upper_rad: np.ndarray,
                 multi: np.ndarray) -> None:
        self._lib = lib
        self._arm = arm
        self._family = FAMILIES[arm.family]
        self._nq = nq = int(arm.nq)
        self._fam = np.asarray(arm.native_constants(), dtype=float)
        if arm.family == "panda" and len(self._fam) != int(lib.armik_panda_count()):
            raise ValueError(f"{len(self._fam)} Panda constants, armik.c reads {int(lib.armik_panda_count())}")
        par = np.zeros(int(lib.armik_par_count()))
        off = getattr(arm, "off", np.zeros(nq))             # the Panda type's joints are its model angles
        sign = getattr(arm, "sign", np.ones(nq))
        for k, block in enumerate((off, sign, lower_rad, upper_rad, np.asarray(multi, dtype=float))):
            par[k * _NQ_MAX:k * _NQ_MAX + nq] = block
        par[5 * _NQ_MAX:5 * _NQ_MAX + 4] = (WRIST_SING_SIN, ELBOW_SING_COS, SHOULDER_SING_MM, LIMIT_TOL_RAD)
        self._par = par

    @classmethod
    def of(cls, arm: Any, lower_rad: np.ndarray, upper_rad: np.ndarray, multi: np.ndarray) -> NativeTrack | None:
        """The C tracking of ``arm``, or None where there is none (another family, no helper)."""
        if getattr(arm, "family", None) not in FAMILIES or int(arm.nq) != (7 if arm.family == "panda" else 6):
            return None
        lib = _armik()
        return None if lib is None else cls(lib, arm, lower_rad, upper_rad, multi)

    def track(self, C: np.ndarray, seed: np.ndarray, max_rows: int, q: np.ndarray, row_ok: np.ndarray,
              reach_any: np.ndarray, sing: np.ndarray, free: float | np.ndarray | None = None) -> bool:
        """``ClosedFormIK._track`` of end-frame columns ``C`` (9, N) from ``seed`` into ``q`` (nq, N) and the
        three (N,) bool arrays, with a Panda-type arm's A7 ``free`` ((N,) or one value); False (nothing
        written) where a row's A1 is undefined: numpy's path holds it."""
        n = C.shape[1]
        Cm = np.ascontiguousarray(self._arm.model_cols(C), dtype=float)
        seed = np.ascontiguousarray(seed, dtype=float)
        if Cm.shape != (9, n) or q.shape != (self._nq, n) or seed.shape != (self._nq,) \
                or any(a.shape != (n,) for a in (row_ok, reach_any, sing)):
            flags = [a.shape for a in (row_ok, reach_any, sing)]
            raise ValueError(f"track: columns {Cm.shape}, joints {q.shape}, seed {seed.shape} and flags {flags} do "
                             f"not match {self._nq} joints of {n} rows")
        # A7 as PandaArm._link6 and _branches take it: numpy's cos and sin of the value given, and it wrapped
        given = np.asarray(0.0 if free is None else free, dtype=float)
        per_row = given.ndim == 1
        q7 = np.atleast_1d(given)
        if per_row and q7.shape[0] != n:
            raise ValueError(f"A7 needs one value per row ({n}), got {q7.shape[0]}")
        c7, s7 = (np.ascontiguousarray(np.cos(q7)), np.ascontiguousarray(np.sin(q7))) if per_row else \
            (np.array([np.cos(q7[0])]), np.array([np.sin(q7[0])]))
        w7 = np.ascontiguousarray(wrap(q7))
        got = self._lib.armik_track(self._family, self._nq, self._fam, self._par, n, Cm, c7, s7, w7, int(per_row),
                                    seed, int(max_rows), q, row_ok, reach_any, sing)
        if got == _HOLD:
            return False
        if got != n:
            raise RuntimeError(f"armik_track answered {got} for {n} rows")
        return True

    def place_multi_turn(self, col: np.ndarray, seed_rad: float, lower_rad: float, upper_rad: float) -> None:
        """``ClosedFormIK._place_multi_turn`` of one multi-turn joint's angles ``col`` (N,), in place."""
        turns = np.empty(len(col))
        self._lib.armik_place_multi_turn(len(col), col, seed_rad, lower_rad, upper_rad, LIMIT_TOL_RAD, turns)
