"""Vectorised G-code lexer: a block of whole lines -> words (line, letter, value) as numpy arrays.

How it works, without a Python object per line or per word:

* every byte gets a character class from a 256-entry table (letter, blank,
  ``;``, ``*``, newline, ``(``, other); only the bytes that are *not* "other"
  (separators) are kept as positions, about a third of the text;
* a word is a letter followed by the "other" bytes up to the next separator, so
  the word's value ends at the next separator position (``sep_pos[k + 1]``);
  the line of each separator is a cumulative count of newlines;
* a comment starts at the first ``;`` (or checksum ``*``) of a line, so words
  at or past it are dropped; ``( ... )`` comments are blanked first, only when
  a ``(`` occurs at all;
* values are parsed right-aligned in one or two 64-bit lanes per word (SWAR:
  byte-wise digit tests and the digits-to-integer step are a few integer ops
  on whole lanes): the digits make an exact integer mantissa (below 10**15 <
  2**53) and the value is ``mantissa / 10**fraction_digits``, correctly
  rounded exactly like ``float()``; longer numbers fall back to ``float()``.

A value that is not ``[+-]digits[.digits]`` is *malformed*; a letter with no
value is *empty*. Blanks between a letter and its number are allowed, as
controllers read them (``G 1 X 5``); an ``E`` written against a number
(``X1e30``) is noted as a possible exponent. The lexer does not judge: the
interpreter decides which words matter (those of known commands) and raises
:class:`GcodeError` there.

Where the C helper is built, :func:`lex_block` runs the same rules as one pass
in C (``fabric/gcode/native_lexer.py``, ``fabric/native/gclex.c``) and lets go
of the interpreter lock meanwhile; :func:`lex_block_numpy` is the reference.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabric.gcode import native_lexer

__all__ = ["Lexed", "lex_block", "lex_block_numpy", "W_OK", "W_EMPTY", "W_BAD"]

# Character classes (the order matters: OTHER = 0 is "part of a value").
C_OTHER, C_LETTER, C_SPACE, C_SEMI, C_STAR, C_NL, C_CR, C_OPEN = 0, 1, 2, 3, 4, 5, 6, 7
_LUT = np.zeros(256, np.uint8)
_LUT[np.frombuffer(b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz", np.uint8)] = C_LETTER
_LUT[np.frombuffer(b" \t\v\f", np.uint8)] = C_SPACE
_LUT[ord(";")] = C_SEMI
_LUT[ord("*")] = C_STAR
_LUT[ord("\n")] = C_NL
_LUT[ord("\r")] = C_CR
_LUT[ord("(")] = C_OPEN

# Word status.
W_OK, W_EMPTY, W_BAD = 0, 1, 2

_MAX_DIGITS = 15                      # mantissas below 10**15 < 2**53 are exact
_PAD = 16                             # zero bytes before the text for right-aligned gathers
_P10 = 10.0 ** np.arange(_MAX_DIGITS + 2)


@dataclass
class Lexed:
    """Words of one block of lines (line numbers are 0-based within the block)."""

    n_lines: int
    line_start: np.ndarray     # (n_lines,) byte offset of each line in the block
    word_line: np.ndarray      # (M,) int64
    word_letter: np.ndarray    # (M,) uint8, upper case ASCII
    word_value: np.ndarray     # (M,) float64, NaN unless status is W_OK
    word_status: np.ndarray    # (M,) uint8 W_OK / W_EMPTY / W_BAD
    word_first: np.ndarray     # (M,) bool: the line's command word (after an ``N`` line number)
    orphan_lines: np.ndarray   # lines with text before their first word (``5 G1``, ``G1 X 5``)
    checksum_bad_lines: np.ndarray  # lines whose ``*nn`` checksum does not match
    code_end: np.ndarray       # (n_lines,) byte offset where the line's comment starts (or its end)
    exponent_lines: np.ndarray  # lines with an E word written against a number (``X1e30``)


def _rep(byte: int) -> np.uint64:
    return np.uint64(byte * 0x0101010101010101)


_M7F, _M80, _M30, _M1E, _M76 = _rep(0x7F), _rep(0x80), _rep(0x30), _rep(0x1E), _rep(0x76)
_FULL = (1 << 64) - 1
_TOP = np.array([0] + [(_FULL << (8 * (8 - b))) & _FULL for b in range(1, 9)], np.uint64)


def _eight_digits(x: np.ndarray) -> np.ndarray:
    """SWAR: eight digit values (0-9, first digit in the lowest byte) -> their integer."""
    x = x * np.uint64(10) + (x >> np.uint64(8))
    m = np.uint64(0x000000FF000000FF)
    x = ((x & m) * np.uint64(100 + (1000000 << 32))
         + ((x >> np.uint64(16)) & m) * np.uint64(1 + (10000 << 32))) >> np.uint64(32)
    return x & np.uint64(0xFFFFFFFF)


def _lane(w: np.ndarray, nb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One 8-byte lane of right-aligned text with ``nb`` bytes inside the number.

    Returns (digit-values lane, dot flags, non-digit flags), flags as 0x80 bits per byte.
    """
    mask = _TOP[nb]
    x = w ^ _M30                                  # digits become 0..9, '.' becomes 0x1E
    nondig = (((x & _M7F) + _M76) | x) & _M80     # byte >= 10
    y = x ^ _M1E
    zero = ~(((y & _M7F) + _M7F) | y | _M7F)      # byte == '.'
    inside = mask & _M80
    dot = zero & inside
    dot_bytes = (dot >> np.uint64(7)) * np.uint64(0xFF)
    return x & mask & ~dot_bytes, dot, nondig & inside & ~dot


def parse_numbers(buf: np.ndarray, start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Parse the byte spans ``buf[start:end]`` as decimal numbers, vectorised.

    The span (after an optional sign) is read right-aligned as one or two
    little-endian 64-bit lanes; digit tests and the digits-to-integer step are
    SWAR bit tricks on whole lanes, so the cost is a few dozen vector ops per
    *word*, not per byte. Returns ``(value, status)``; ``buf`` must have at
    least ``_PAD`` bytes before any span.
    """
    m = len(start)
    if m == 0:
        return np.full(0, np.nan), np.zeros(0, np.uint8)
    length = end - start
    first = buf[start]
    signed = ((first == ord("-")) | (first == ord("+"))) & (length > 0)
    body = length - signed                       # chars after the sign
    wide = body > _MAX_DIGITS                    # too long for the exact path
    nb = np.minimum(body, _MAX_DIGITS)
    two = bool(nb.max() > 8)
    words = np.ndarray((len(buf) - 7,), np.uint64, buffer=buf, strides=(1,))   # every unaligned 8-byte word
    lo_d, lo_dot, lo_bad = _lane(words.take(end - 8), np.minimum(nb, 8))
    raw = _eight_digits(lo_d)
    ndot = np.bitwise_count(lo_dot)
    bad = lo_bad != 0
    dotk = (np.uint64(7) - (np.bitwise_count(lo_dot - np.uint64(1)) >> np.uint64(3))).astype(np.int64)
    if two:
        hi_d, hi_dot, hi_bad = _lane(words.take(end - 16), np.maximum(nb - 8, 0))
        raw = raw + _eight_digits(hi_d) * np.uint64(100000000)
        ndot = ndot + np.bitwise_count(hi_dot)
        bad |= hi_bad != 0
        dot_hi = (np.uint64(15) - (np.bitwise_count(hi_dot - np.uint64(1)) >> np.uint64(3))).astype(np.int64)
        dotk = np.where(hi_dot != 0, dot_hi, dotk)
    has_dot = ndot == 1
    dotk = np.where(has_dot, dotk, 0)
    # Remove the dot's place: digits left of it were counted one place too high. In floats,
    # exactly: raw = hi * 10^(k+1) + lo with lo < 10^k, so floor(raw / 10^(k+1)) = hi (the
    # fraction is < 0.1) and the mantissa hi * 10^k + lo = raw - 9 * hi * 10^k, all < 2^53.
    raw_f = raw.astype(np.float64)
    p10 = _P10[dotk]
    hi = np.floor(raw_f / (p10 * 10.0))
    mant = np.where(has_dot, raw_f - 9.0 * hi * p10, raw_f)
    val = mant / p10                             # correctly rounded, like float()
    val = np.where(first == ord("-"), -val, val)
    ok = (length > 0) & ~bad & (ndot <= 1) & (body - ndot >= 1) & ~wide
    value = np.where(ok, val, np.nan)
    status = np.where(ok, np.uint8(W_OK), np.where(length == 0, np.uint8(W_EMPTY), np.uint8(W_BAD)))
    for i in np.flatnonzero((length > 0) & wide):   # rare: very long numbers
        text = bytes(buf[start[i]:end[i]])
        body_txt = text[1:] if text[:1] in (b"-", b"+") else text
        if body_txt.replace(b".", b"", 1).isdigit() and np.isfinite(float(text)):
            value[i] = float(text)
            status[i] = W_OK
    return value, status


def _blank_parens(cls: np.ndarray) -> None:
    """Blank ``( ... )`` comments in place (chars inside, and the parens, become spaces)."""
    pos = np.arange(len(cls))
    nl = np.maximum.accumulate(np.where(cls == C_NL, pos, -1))
    opened = np.maximum.accumulate(np.where(cls == C_OPEN, pos, -1))
    close = np.maximum.accumulate(np.where(cls == 255, pos, -1))   # 255 marks ')'
    close_before = np.concatenate([[-1], close[:-1]])
    inside = (opened > close_before) & (opened > nl)
    cls[inside] = C_SPACE
    cls[cls == 255] = C_OTHER                                    # a stray ')'


def _empty() -> Lexed:
    z = np.zeros(0, np.int64)
    return Lexed(0, z, z, z.astype(np.uint8), z.astype(float), z.astype(np.uint8), z.astype(bool), z, z, z, z)


def lex_block(block: bytes | memoryview) -> Lexed:
    """Lex whole lines of G-code (``block`` may or may not end with a newline): in C where it is built."""
    if len(block) == 0:
        return _empty()
    arrays = native_lexer.lex_arrays(block)
    return lex_block_numpy(block) if arrays is None else Lexed(**arrays)


def lex_block_numpy(block: bytes | memoryview) -> Lexed:
    """:func:`lex_block` by numpy (the reference the C lexer is held to)."""
    n = len(block)
    if n == 0:
        return _empty()
    buf = np.zeros(_PAD + n + 1 + _PAD, np.uint8)
    buf[_PAD:_PAD + n] = np.frombuffer(block, np.uint8)
    buf[_PAD + n] = ord("\n")
    cls = _LUT.take(buf)
    cls[:_PAD] = C_SPACE
    cls[_PAD + n + 1:] = C_SPACE
    # A lone CR is a line break (old Mac files); CR LF is a blank before the LF.
    cr = np.flatnonzero(cls == C_CR)
    if len(cr):
        cls[cr] = np.where(buf[cr + 1] == ord("\n"), C_SPACE, C_NL)
    if (cls == C_OPEN).any():
        cls[buf == ord(")")] = 255
        _blank_parens(cls)
    sep_pos = np.flatnonzero(cls != 0)
    sep_cls = cls[sep_pos]
    is_nl = sep_cls == C_NL
    nl_k = np.flatnonzero(is_nl)
    nl_pos = sep_pos[nl_k]
    if bytes(block[-1:]) == b"\n":
        nl_pos = nl_pos[:-1]                      # the pad newline closes no line of its own
    n_lines = len(nl_pos)
    line_start = np.concatenate([[_PAD], nl_pos[:-1] + 1]) if n_lines else np.zeros(0, np.int64)
    per_line = np.diff(nl_k, prepend=-1, append=len(sep_pos) - 1)
    line_of_sep = np.repeat(np.arange(len(per_line), dtype=np.int64), per_line)   # a newline ends its line
    # Where each line's comment starts (first ';' or '*').
    code_end = nl_pos.copy()
    cs = np.flatnonzero((sep_cls == C_SEMI) | (sep_cls == C_STAR))
    star_lines = np.zeros(0, np.int64)
    star_k = np.zeros(0, np.int64)
    if len(cs):
        cs_line = line_of_sep[cs]
        first = np.concatenate([[True], cs_line[1:] != cs_line[:-1]])
        cs, cs_line = cs[first], cs_line[first]
        code_end[cs_line] = sep_pos[cs]
        is_star = sep_cls[cs] == C_STAR
        star_lines, star_k = cs_line[is_star], cs[is_star]
    # Words: a letter and the bytes up to the next separator, before the comment.
    li = np.flatnonzero(sep_cls == C_LETTER)
    w_pos = sep_pos[li]
    w_line = line_of_sep[li]
    keep = w_pos < code_end[w_line]
    li, w_pos, w_line = li[keep], w_pos[keep], w_line[keep]
    w_start, w_end = w_pos + 1, sep_pos[li + 1]
    joined = _join_spaced_values(sep_pos, sep_cls, li, w_start, w_end)
    value, status = parse_numbers(buf, w_start, w_end)
    letter = buf[w_pos] & np.uint8(0xDF)
    # an E against a number ("X1e30", "X1E30"): an exponent, or an E word with no blank before it
    e_word = np.flatnonzero((letter == ord("E")) & (w_end > w_start))
    before = buf[w_pos[e_word] - 1]
    exponent_lines = np.unique(w_line[e_word[((before >= ord("0")) & (before <= ord("9"))) | (before == ord("."))]])
    # Command word: first of its line, after a leading N line number.
    first = np.concatenate([[True], w_line[1:] != w_line[:-1]]) if len(w_line) else np.zeros(0, bool)
    lineno = first & (letter == ord("N"))
    if lineno.any():
        keepw = ~lineno
        w_line, letter, value, status = w_line[keepw], letter[keepw], value[keepw], status[keepw]
        first = np.concatenate([[True], w_line[1:] != w_line[:-1]]) if len(w_line) else first[keepw]
    # Orphans: "other" bytes that follow a blank/comment/newline rather than a letter.
    loose = (sep_pos[1:] - sep_pos[:-1] > 1) & (sep_cls[:-1] != C_LETTER)
    loose[joined] = False                         # text that became a word's value ("X 5")
    gap = np.flatnonzero(loose)
    o_pos = sep_pos[gap] + 1
    o_line = line_of_sep[gap] + is_nl[gap]
    inl = o_line < n_lines
    o_pos, o_line = o_pos[inl], o_line[inl]
    orphan_lines = np.unique(o_line[o_pos < code_end[o_line]])
    bad_sum = _check_sums(buf, line_start, star_lines, star_k, sep_pos)
    return Lexed(n_lines=n_lines, line_start=line_start - _PAD, word_line=w_line,
                 word_letter=letter, word_value=value, word_status=status, word_first=first,
                 orphan_lines=orphan_lines, checksum_bad_lines=bad_sum, code_end=code_end - _PAD,
                 exponent_lines=exponent_lines)


def _join_spaced_values(sep_pos: np.ndarray, sep_cls: np.ndarray, li: np.ndarray, w_start: np.ndarray,
                        w_end: np.ndarray) -> np.ndarray:
    """Words written with blanks between letter and number (``X 5``, ``G 1``), as controllers read them.

    A word whose value is empty and whose letter is followed by blanks, then by
    value bytes, takes those bytes as its value (``w_start`` and ``w_end`` are
    changed in place). Returns the separator indices (the last blank before
    each value) whose following text was taken, so it is not an orphan. A
    letter followed by blanks and another letter or a comment stays empty
    (``G28 X Y``).
    """
    spaced = np.flatnonzero((w_end == w_start) & (sep_cls[li + 1] == C_SPACE))
    if len(spaced) == 0:
        return spaced
    n = len(sep_pos)
    gap = np.zeros(n, bool)
    gap[:-1] = sep_pos[1:] - sep_pos[:-1] > 1     # value bytes follow separator i
    stop = np.where((sep_cls != C_SPACE) | gap, np.arange(n), n)
    first = np.minimum.accumulate(stop[::-1])[::-1]   # the first stop at or after each separator
    k = first[li[spaced] + 1]                     # the pad newline always stops: k < n
    took = sep_cls[k] == C_SPACE
    spaced, k = spaced[took], k[took]
    w_start[spaced] = sep_pos[k] + 1
    w_end[spaced] = sep_pos[k + 1]
    return k


def _check_sums(buf: np.ndarray, line_start: np.ndarray, star_lines: np.ndarray,
                star_k: np.ndarray, sep_pos: np.ndarray) -> np.ndarray:
    """Lines whose ``*nn`` checksum is not the XOR of the bytes before the ``*``."""
    if len(star_lines) == 0:
        return star_lines
    star = sep_pos[star_k]
    starts = line_start[star_lines]
    idx = np.empty(2 * len(star), np.int64)
    idx[0::2], idx[1::2] = starts, star
    xor = np.bitwise_xor.reduceat(buf, idx)[0::2]
    xor = np.where(star > starts, xor, 0)
    want, st = parse_numbers(buf, star + 1, sep_pos[star_k + 1])
    ok = (st == W_OK) & (want == xor)
    return star_lines[~ok]
