"""Fast text of numeric columns: vectorised fixed-point formatting, the same characters as ``"%.<d>f"``.

Formatting a million rows with ``%`` costs some 2.5 us a row in Python. Here
every column becomes a byte matrix at once: the value is scaled to an integer
of ``decimals`` places (``rint(|v| * 10**d)``), its digits are peeled off with
integer division, right-aligned in a fixed-width cell padded with zero bytes;
the cells of all columns are joined with separators, and the zero bytes are
dropped from the flattened matrix, which leaves the text of the block.

Exactness. ``printf`` rounds the exact binary value; ``rint`` of the scaled
double can only disagree when the scaled value lies within its own rounding
error of a half (a tie, or nearly). Those few values (and non-finite or huge
ones) are formatted by Python itself and written into their cells, so the
output is always the same characters as ``"%.<d>f" % v``.

Trimmed columns (RAPID's numbers) drop the trailing zeros of the fraction, and
the point when nothing is left after it, and write a value that rounds to
zero without its sign: while the fractional digits are peeled off from the
last one, a digit is blanked as long as every digit after it was a zero.
A :class:`ChoiceColumn` writes one of a few fixed texts per row (names).

The C helper. Rows of plain columns (integers, fixed decimals, constant
texts: a CSV's) are written by ``fabric/native/numtext.c`` where it could be
built (:mod:`fabric.native`): the same algorithm, tie band and fallback to
exact rounding (``snprintf``), so the same characters, about five times
faster and without the GIL; numpy's path above stands in wherever it cannot
(no compiler, trimmed or choice columns, a value not finite).
"""
from __future__ import annotations

import ctypes
from collections.abc import Sequence

import numpy as np

from fabric import native

__all__ = ["format_rows", "FixedColumn", "ChoiceColumn", "Column", "trimmed_text", "native_rows", "SIGNATURES"]

_ZERO, _DOT, _MINUS = ord("0"), ord("."), ord("-")
_MAX_SCALED = 1e15          # beyond this the int64 digits path is not trusted: Python formats the value
_TIE_TOL_R = 1e-15          # relative width of the band around a half that goes to Python
_POW10 = 10 ** np.arange(1, 19, dtype=np.int64)


class FixedColumn:
    """One column: values and their decimals (``0``: an integer column, written like ``%d``).

    ``trim``: written as :func:`trimmed_text` does (trailing zeros of the
    fraction dropped, no ``-0``); only for columns with decimals.
    """

    def __init__(self, values: np.ndarray, decimals: int, trim: bool = False) -> None:
        if not 0 <= decimals <= 12:
            raise ValueError(f"decimals must be in 0..12, got {decimals}")
        if trim and decimals == 0:
            raise ValueError("a trimmed column needs decimals")
        self.values = np.asarray(values)
        self.decimals = decimals
        self.trim = trim

    def __len__(self) -> int:
        return len(self.values)


class ChoiceColumn:
    """One column of fixed texts: row ``i`` writes ``texts[index[i]]`` (texts without zero bytes)."""

    def __init__(self, index: np.ndarray, texts: list[bytes]) -> None:
        if any(b"\0" in t for t in texts):
            raise ValueError("choice texts cannot hold zero bytes")
        self.index = np.asarray(index, dtype=np.intp)
        self.texts = texts

    def __len__(self) -> int:
        return len(self.index)


def trimmed_text(v: float, decimals: int) -> str:
    """``"%.<d>f" % v`` without the trailing zeros of the fraction (nor a bare point); ``-0`` is ``0``."""
    text = f"{v:.{decimals}f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _digits_count(iv: np.ndarray) -> np.ndarray:
    """Number of decimal digits of non-negative integers (1 for 0)."""
    n = np.ones(iv.shape, dtype=np.uint8)
    top = int(iv.max(initial=0))
    p = 10
    while p <= top:
        n += iv >= p
        p *= 10
    return n


def _divmod(x: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    # floor division by a scalar is numpy's fast path (libdivide); np.divmod is not
    q = x // k
    return q, x - q * k


def _python_text(v: float, decimals: int, trim: bool) -> bytes:
    return (trimmed_text(v, decimals) if trim else f"%.{decimals}f" % v).encode("ascii")


def _cells(col: FixedColumn) -> np.ndarray:
    """(width, n) uint8: the text of every value right-aligned in its column, zero bytes above it."""
    v, d = col.values, col.decimals
    n = len(v)
    if v.dtype.kind in "iu":
        neg = v < 0
        iv = v.astype(np.int64).view(np.uint64).copy()
        iv[neg] = ~iv[neg] + np.uint64(1)          # |v| in two's complement: the smallest int64 too
        slow = np.zeros(n, dtype=bool)
    else:
        v = v.astype(np.float64, copy=False)
        neg = np.signbit(v)
        with np.errstate(over="ignore"):            # a huge value scales to inf: Python writes it
            scaled = np.abs(v) * 10.0 ** d
        rounded = np.rint(scaled)
        with np.errstate(invalid="ignore"):
            # near a half (or not finite, or huge): Python decides
            off = np.abs(scaled - rounded)
            slow = ~(off < 0.5 - scaled * _TIE_TOL_R) | ~(scaled < _MAX_SCALED)
        if slow.any():
            rounded[slow] = 0.0
        iv = rounded.astype(np.int64)
    if iv.max(initial=0) < 2**32 and 10 ** d < 2**32:
        iv = iv.astype(np.uint32)                   # the fast integer division path (10**d must fit too)
    ip, fp = _divmod(iv, 10 ** d) if d else (iv, iv)     # integer and fractional digits (fp unread if d is 0)
    n_int = _digits_count(ip)
    slow_rows = np.flatnonzero(slow)
    slow_text = [_python_text(float(v[i]), d, col.trim) for i in slow_rows]
    width = max(int(n_int.max(initial=1)) + 1 + (d + 1 if d else 0), max(map(len, slow_text), default=0))
    # built transposed: one contiguous row of bytes per character position
    cells = np.zeros((width, n), dtype=np.uint8)
    pos = width - 1
    trailing = np.ones(n, dtype=bool) if col.trim else None     # every fractional digit so far was a zero
    for _ in range(d):                              # fractional digits, then the point
        fp, digit = _divmod(fp, 10)
        cells[pos] = digit
        cells[pos] += _ZERO
        if trailing is not None:
            trailing &= digit == 0
            cells[pos] *= ~trailing
        pos -= 1
    if d:
        cells[pos] = _DOT
        if trailing is not None:
            cells[pos] *= ~trailing
        pos -= 1
    rest = ip                                       # integer digits (as many as each value has)
    for j in range(int(n_int.max(initial=1))):
        rest, digit = _divmod(rest, 10)
        cells[pos - j] = digit
        cells[pos - j] += _ZERO
        if j:
            cells[pos - j] *= n_int > j
    rows = np.flatnonzero(neg & (iv != 0) if col.trim else neg)
    cells[pos - n_int[rows].astype(np.intp), rows] = _MINUS      # the sign (a cell may be over 255 wide)
    for i, text in zip(slow_rows, slow_text, strict=True):       # the values Python formats
        cells[:, i] = 0
        cells[width - len(text):, i] = np.frombuffer(text, dtype=np.uint8)
    return cells


def _choice_cells(col: ChoiceColumn) -> np.ndarray:
    """(width, n) uint8: the chosen text of every row, zero bytes after it."""
    width = max(map(len, col.texts), default=0)
    table = np.zeros((width, len(col.texts)), dtype=np.uint8)
    for k, text in enumerate(col.texts):
        table[:len(text), k] = np.frombuffer(text, dtype=np.uint8)
    return table[:, col.index]


Column = FixedColumn | ChoiceColumn | bytes


def format_rows(columns: Sequence[Column], sep: bytes = b",") -> bytes:
    """Text of rows: the columns in order, ``sep`` between them, ``\\n`` after each row.

    A ``bytes`` column is a constant written on every row (e.g. ``b""`` for an empty field).
    """
    n = next(len(c) for c in columns if not isinstance(c, bytes))
    text = _native_rows(columns, sep, n)
    if text is not None:
        return text
    parts: list[np.ndarray] = []
    for k, col in enumerate(columns):
        if k and sep:
            parts.append(_constant(sep, n))
        if isinstance(col, FixedColumn):
            parts.append(_cells(col))
        elif isinstance(col, ChoiceColumn):
            parts.append(_choice_cells(col))
        else:
            parts.append(_constant(col, n))
    parts.append(_constant(b"\n", n))
    flat = np.concatenate(parts, axis=0).T.ravel()       # row after row
    return flat[flat != 0].tobytes()


_KIND_FLOAT, _KIND_INT, _KIND_TEXT = 0, 1, 2      # numtext.c's column kinds
_ROW_BOUND = 40              # bytes a number of up to 12 decimals takes at most on the C helper's fast path


def _native_rows(columns: Sequence[Column], sep: bytes, n: int) -> bytes | None:
    """:func:`format_rows` by the C helper (``fabric/native/numtext.c``, the same characters), or None where it
    cannot: no helper, a choice or trimmed column, a separator of more than one byte, a value not finite (or
    of over 63 characters)."""
    lib = _numtext()
    if lib is None or len(sep) > 1:
        return None
    k = len(columns)
    kinds, decimals = (ctypes.c_int * k)(), (ctypes.c_int * k)()
    data, texts, text_len = (ctypes.c_void_p * k)(), (ctypes.c_char_p * k)(), (ctypes.c_long * k)()
    stride = (ctypes.c_long * k)()
    keep: list[np.ndarray] = []             # the arrays the pointers point into, alive through the call
    cap = 1
    for j, col in enumerate(columns):
        if isinstance(col, bytes):
            kinds[j], texts[j], text_len[j] = _KIND_TEXT, col, len(col)
            cap += len(col) + 2
            continue
        if not isinstance(col, FixedColumn) or col.trim:
            return None
        dt = col.values.dtype
        ints = dt.kind in "iu"
        if ints and (col.decimals or (dt.itemsize == 8 and dt.kind == "u")):
            return None                         # integers read as fixed-point, or past int64: numpy's path
        values = _readable(col.values, np.dtype(np.int64 if ints else np.float64))
        assert values.dtype == (np.int64 if ints else np.float64) and values.ndim == 1   # what kinds[j] says
        keep.append(values)
        kinds[j], decimals[j] = (_KIND_INT, 0) if ints else (_KIND_FLOAT, col.decimals)
        data[j], stride[j] = values.ctypes.data, values.strides[0] // values.itemsize
        cap += _ROW_BOUND + 1
    cap = max(cap * n + 128, 128)
    out = np.empty(cap, dtype=np.uint8)     # not zeroed: only the bytes written are read
    written = lib.numtext_rows(n, k, kinds, data, stride, decimals, texts, text_len, sep[:1] or b"\0",
                               out, cap, _MAX_SCALED, _TIE_TOL_R)
    if written < 0:                         # not finite or too long, or (never expected) no room: numpy writes it
        return None
    return out[:written].tobytes()


def _readable(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """``values`` as the C helper reads them: 1-D of ``dtype`` (native order), any whole-element stride (a
    column of rows, e.g. ``xyz[:, 0]``, read where it lies); copied only where that is not so."""
    v = values.reshape(-1) if values.ndim != 1 else values
    if v.dtype == dtype and v.dtype.isnative and v.strides[0] % dtype.itemsize == 0 and v.strides[0] >= 0:
        return v
    return np.ascontiguousarray(v, dtype=dtype)


# The columns' data pointers are an array of void pointers, each set from an array _readable made of the
# column's kind (float64 or int64, native order): the kinds array says which the helper reads at each.
SIGNATURES: dict[str, native.Signature] = {
    "numtext_rows": (ctypes.c_long, [
        ctypes.c_long, ctypes.c_int, ctypes.POINTER(ctypes.c_int), ctypes.POINTER(ctypes.c_void_p),
        ctypes.POINTER(ctypes.c_long), ctypes.POINTER(ctypes.c_int), ctypes.POINTER(ctypes.c_char_p),
        ctypes.POINTER(ctypes.c_long), ctypes.c_char, native.array(np.uint8, out=True), ctypes.c_long,
        ctypes.c_double, ctypes.c_double]),
}


def native_rows() -> bool:
    """Whether plain rows are written by the C helper here (else by numpy)."""
    return _numtext() is not None


use_native = True           # False: numpy writes every row even where the C helper could (tests compare the two)


def _numtext() -> ctypes.CDLL | None:
    return native.bound("numtext", SIGNATURES) if use_native else None


def _constant(text: bytes, n: int) -> np.ndarray:
    return np.broadcast_to(np.frombuffer(text, dtype=np.uint8)[:, None], (len(text), n))
