"""The look-ahead's cruise caps in C (``fabric/native/lookahead.c``): the same caps as numpy's ``_caps``, to
the bit, in one pass over the rows. :func:`caps` answers None where there is no helper (no compiler, or
``FABRIC_NATIVE=0``): numpy's path then runs."""
from __future__ import annotations

import ctypes

import numpy as np

from fabric import native

__all__ = ["caps", "available", "SIGNATURES"]

_L = ctypes.c_long
_F8, _F8_OUT = native.array(np.float64), native.array(np.float64, out=True)
SIGNATURES: dict[str, native.Signature] = {
    "lookahead_caps": (None, [_L, ctypes.c_int, native.array(np.float64, ndim=2), _F8, _L, native.array(np.int64),
                              _F8, _F8, _F8, _F8_OUT, native.array(np.bool_, out=True),
                              native.array(np.int64, out=True), native.array(np.bool_, out=True)]),
}


def _lookahead() -> ctypes.CDLL | None:
    return native.bound("lookahead", SIGNATURES)


def available() -> bool:
    return _lookahead() is not None


def caps(cap_prog: np.ndarray, q: np.ndarray, q0: np.ndarray, Ls: np.ndarray, seg: np.ndarray,
         vlim: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """``lookahead._caps``: caps, slowed mask, limiting joint (per segment) and moving-joint rows; None
    without the helper."""
    lib = _lookahead()
    if lib is None:
        return None
    n, nq = q.shape
    m = len(seg)
    f8 = [np.ascontiguousarray(a, dtype=float) for a in (q, q0, Ls, cap_prog, vlim)]
    q, q0, Ls, cap_prog, vlim = f8
    seg = np.ascontiguousarray(seg, dtype=np.int64)
    if Ls.shape != (m,) or cap_prog.shape != (m,) or q0.shape != (nq,) or vlim.shape != (nq,):
        raise ValueError("caps: segments, lengths, caps, joints or limits do not match")
    if m and (seg[0] < 0 or seg[-1] >= n or np.any(np.diff(seg) <= 0)):
        raise ValueError("caps: the segments' rows must be ascending rows of q")
    cap, worst = np.empty(m), np.empty(m, dtype=np.int64)
    slowed, reorient = np.empty(m, dtype=bool), np.empty(n, dtype=bool)
    if seg.shape != (m,):
        raise ValueError("caps: the segments must be one row index each")
    lib.lookahead_caps(n, nq, q, q0, m, seg, Ls, vlim, cap_prog, cap, slowed, worst, reorient)
    return cap, slowed, worst.astype(np.intp, copy=False), reorient
