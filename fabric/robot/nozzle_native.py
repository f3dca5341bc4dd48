"""The nozzle frames, the IK's flange columns and the TCP quaternions of a path in C (``fabric/native/nozzle.c``).

:class:`fabric.robot.nozzle_frames.NozzleFrames` and ``_PathSolver.flange_cols`` hand their whole-path work
here: the same arithmetic row by row, where numpy makes a pass over memory per operation and keeps every
temporary of N rows. Each function answers None where there is no helper (no compiler, or
``FABRIC_NATIVE=0``): numpy's path then runs. The cosines and sines of the rotations are numpy's, taken by
the caller, so the columns the IK reads are numpy's to the bit.
"""
from __future__ import annotations

import ctypes

import numpy as np

from fabric import native
from fabric.robot.frames import QUAT_SIGN_TOL

__all__ = ["frames", "flange_cols", "quats", "available", "SIGNATURES"]

_V, _M = native.array(np.float64, ndim=1), native.array(np.float64, ndim=2)      # vectors, columns (3, N)
_M_OUT = native.array(np.float64, ndim=2, out=True)
_L, _I = ctypes.c_long, ctypes.c_int
SIGNATURES: dict[str, native.Signature] = {
    "nozzle_frames": (None, [_L, _M, _I, _M, _M_OUT, _M_OUT]),
    "nozzle_flange_cols": (None, [_L, _M, _M, _M, _M, _I, _V, _V, _I, _M, _M_OUT]),
    "nozzle_quats": (None, [_L, _M, _V, _V, _V, _V, _I, ctypes.c_double, _M_OUT]),
}


def _nozzle() -> ctypes.CDLL | None:
    return native.bound("nozzle", SIGNATURES)


def available() -> bool:
    return _nozzle() is not None


def _f8(a: np.ndarray | float) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=float)


def _check(rows: int, n: int, what: str) -> None:
    """A per-row input has one value for all rows or one per row."""
    if rows not in (1, n):
        raise ValueError(f"{what} has {rows} rows for {n}")


def _rows3(a: np.ndarray, what: str) -> None:
    """Columns of 3-vectors: (3, N)."""
    if a.ndim != 2 or a.shape[0] != 3:
        raise ValueError(f"{what} must be (3, N), not {a.shape}")


def frames(z0: np.ndarray, xr: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``x0, y0`` (3, N) of ``NozzleFrames`` for unit nozzle axes ``z0`` ((3, 1) or (3, N)) and references
    ``xr`` (3, N); None without the helper."""
    lib = _nozzle()
    if lib is None:
        return None
    n = xr.shape[1]
    _check(z0.shape[1], n, "z0")
    _rows3(z0, "z0")
    _rows3(xr, "xr")
    z0, xr = _f8(z0), _f8(xr)
    x0, y0 = np.empty((3, n)), np.empty((3, n))
    lib.nozzle_frames(n, z0, int(z0.shape[1] != 1), xr, x0, y0)
    return x0, y0


def flange_cols(p: np.ndarray, x0: np.ndarray, y0: np.ndarray, z0: np.ndarray, c: np.ndarray | float,
                s: np.ndarray | float, tool_inv_T: np.ndarray) -> np.ndarray | None:
    """``_PathSolver.flange_cols`` of every row (9, N): positions ``p`` (3, N), frames ``x0, y0`` (3, N) and
    ``z0`` ((3, 1) or (3, N)), ``c, s`` the rotation's cosine and sine (one or (N,)); None without the helper."""
    lib = _nozzle()
    if lib is None:
        return None
    n = p.shape[1]
    for a, what in ((p, "p"), (x0, "x0"), (y0, "y0"), (z0, "z0")):
        _rows3(a, what)
    if x0.shape != p.shape or y0.shape != p.shape:
        raise ValueError(f"the frames {x0.shape}, {y0.shape} do not match the positions {p.shape}")
    p, x0, y0, z0 = _f8(p), _f8(x0), _f8(y0), _f8(z0)
    c, s = np.atleast_1d(_f8(c)), np.atleast_1d(_f8(s))
    m = _f8(np.stack([tool_inv_T[:3, 3], tool_inv_T[:3, 2], tool_inv_T[:3, 1]]))
    out = np.empty((9, n))
    _check(z0.shape[1], n, "z0")
    _check(c.shape[0], n, "the rotation")
    if s.shape != c.shape:
        raise ValueError(f"the rotation's cosines {c.shape} and sines {s.shape} differ")
    lib.nozzle_flange_cols(n, p, x0, y0, z0, int(z0.shape[1] != 1), c, s, int(c.shape[0] != 1), m, out)
    return out


def quats(x0: np.ndarray, B: np.ndarray, qb: np.ndarray, theta_rad: np.ndarray | float) -> np.ndarray | None:
    """``NozzleFrames.quats`` with one nozzle axis (frame ``B``, its quaternion ``qb``) of rows whose x axes
    are ``x0`` (3, N) at rotations ``theta_rad`` (one or (N,)): (N, 4); None without the helper."""
    lib = _nozzle()
    if lib is None:
        return None
    _rows3(x0, "x0")
    n = x0.shape[1]
    x0 = _f8(x0)
    theta = np.atleast_1d(_f8(theta_rad))
    bx, by, qb = _f8(B[:, 0]), _f8(B[:, 1]), _f8(qb)
    if B.shape != (3, 3) or qb.shape != (4,):
        raise ValueError(f"B must be (3, 3) and qb (4,), not {B.shape} and {qb.shape}")
    out = np.empty((n, 4))
    _check(theta.shape[0], n, "the rotation")
    lib.nozzle_quats(n, x0, bx, by, qb, theta, int(theta.shape[0] != 1), QUAT_SIGN_TOL, out)
    return out
