"""The G-code lexer in C (``fabric/native/gclex.c``): one pass over a block's bytes, no interpreter lock held.

:func:`lex_arrays` answers the arrays of :class:`fabric.gcode.lexer.Lexed`, or
None where the C helper is not here (no compiler, ``FABRIC_NATIVE=0``): the
lexer then takes its numpy path, which gives the same arrays (a test lexes
fuzzed texts both ways and compares them).
"""
from __future__ import annotations

import ctypes
from typing import Any

import numpy as np

from fabric import native

__all__ = ["lex_arrays", "available", "SIGNATURES"]

_U1, _I8, _F8 = (native.array(t, out=True) for t in (np.uint8, np.int64, np.float64))
SIGNATURES: dict[str, native.Signature] = {
    # the text, its length, then cls, line_start, code_end, word_line, word_letter, word_value, word_status,
    # word_first, orphan, badsum, exponent (lines), counts
    "gclex": (ctypes.c_long, [ctypes.c_char_p, ctypes.c_long, _U1, _I8, _I8, _I8, _U1, _F8, _U1, _U1, _I8, _I8, _I8,
                              _I8]),
    "gclex_bounds": (None, [ctypes.c_char_p, ctypes.c_long, _I8]),
}


def _gclex() -> ctypes.CDLL | None:
    return native.bound("gclex", SIGNATURES)


def available() -> bool:
    """Whether blocks are lexed in C here."""
    return _gclex() is not None


def lex_arrays(block: bytes | memoryview) -> dict[str, Any] | None:
    """The lexed arrays of a non-empty block of whole lines (the fields of ``Lexed``), or None without C.

    The arrays are views of buffers sized by a first count (line breaks, letters)."""
    lib = _gclex()
    if lib is None:
        return None
    data = bytes(block)
    n = len(data)
    bounds = np.zeros(2, np.int64)
    lib.gclex_bounds(data, n, bounds)
    lines_cap, words_cap = int(bounds[0]), int(bounds[1]) + 1
    cls = np.empty(n + 1, np.uint8)
    line_start, code_end = np.empty(lines_cap, np.int64), np.empty(lines_cap, np.int64)
    word_line, word_value = np.empty(words_cap, np.int64), np.empty(words_cap, np.float64)
    word_letter, word_status, word_first = (np.empty(words_cap, np.uint8) for _ in range(3))
    orphan, badsum, exponent = (np.empty(lines_cap, np.int64) for _ in range(3))
    counts = np.zeros(5, np.int64)
    lib.gclex(data, n, cls, line_start, code_end, word_line, word_letter, word_value, word_status, word_first,
              orphan, badsum, exponent, counts)
    lines, words, n_orphan, n_bad, n_exp = (int(c) for c in counts)
    return {"n_lines": lines, "line_start": line_start[:lines], "code_end": code_end[:lines],
            "word_line": word_line[:words], "word_letter": word_letter[:words], "word_value": word_value[:words],
            "word_status": word_status[:words], "word_first": word_first[:words].view(np.bool_),
            "orphan_lines": orphan[:n_orphan], "checksum_bad_lines": badsum[:n_bad],
            "exponent_lines": exponent[:n_exp]}
