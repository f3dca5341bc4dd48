"""The look-ahead's cruise caps in C (``fabric/native/lookahead.c``): the same caps as numpy's ``_caps``, to
the bit, in one pass over the rows. :func:`caps` answers None where there is no helper (no compiler, or
``FABRIC_NATIVE=0``): numpy's path then runs."""
from __future__ import annotations

import ctypes

import numpy as np

from fabric import native

__all__ = ["caps", "available"]

_P = ctypes.c_void_p
_L = ctypes.c_long
_SIGNATURES: dict[str, native.Signature] = {
    "lookahead_caps": (None, [_L, ctypes.c_int, _P, _P, _L, _P, _P, _P, _P, _P, _P, _P, _P]),
}


def _lookahead() -> ctypes.CDLL | None:
    return native.bound("lookahead", _SIGNATURES)


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
    lib.lookahead_caps(n, nq, q.ctypes.data, q0.ctypes.data, m, seg.ctypes.data, Ls.ctypes.data, vlim.ctypes.data,
                       cap_prog.ctypes.data, cap.ctypes.data, slowed.ctypes.data, worst.ctypes.data,
                       reorient.ctypes.data)
    return cap, slowed, worst.astype(np.intp, copy=False), reorient
