"""A block's command table: lexed words -> one row per known command and its parameters, with word errors.

Every known command (:data:`fabric.gcode.commands.KNOWN`) of a block becomes
one row; its parameter words fill the columns of :data:`PARAMS` (NaN where a
word is absent, ``has`` says which are present). Malformed words, values out
of range, orphan text, bad checksums, a letter repeated on a line and numbers
in exponent form are collected as :class:`LineError` (the interpreter raises
the first one); unknown commands are counted by name.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabric.gcode.commands import COL, FLAG_OK, PARAMS, code_of
from fabric.gcode.lexer import W_BAD, W_EMPTY, W_OK, Lexed

__all__ = ["LineError", "CommandTable", "command_table", "MAX_ABS_VALUE"]

MAX_ABS_VALUE = 1e9          # any parameter beyond this (mm, mm/min, deg C...) is an error


@dataclass(frozen=True)
class LineError:
    """An error found on line ``line`` (0-based within the block)."""

    line: int
    message: str


@dataclass
class CommandTable:
    """The known commands of one block, one row each."""

    line: np.ndarray           # (k,) int64 0-based line in the block
    code: np.ndarray           # (k,) int64 command code
    par: np.ndarray            # (k, len(PARAMS)) float64, NaN where the word is absent
    has: np.ndarray            # (k, len(PARAMS)) bool

    def __len__(self) -> int:
        return len(self.code)

    def rows(self, sel: np.ndarray) -> CommandTable:
        """The table of some rows."""
        return CommandTable(self.line[sel], self.code[sel], self.par[sel], self.has[sel])


def command_table(lx: Lexed, errors: list[LineError], unknown: dict[str, int]) -> CommandTable:
    """The command table of a lexed block; errors appended to ``errors``, unknown commands counted in ``unknown``."""
    # the command word of each line: known, unknown, or a malformed G/M number
    wf = np.flatnonzero(lx.word_first)
    f_letter, f_value = lx.word_letter[wf], lx.word_value[wf]
    f_status, f_line = lx.word_status[wf], lx.word_line[wf]
    code = code_of(f_letter, f_value, f_status == W_OK)
    gm = (f_letter == ord("G")) | (f_letter == ord("M"))
    bad_gm = gm & (f_status == W_BAD)
    bad = np.flatnonzero(bad_gm)
    if len(bad):
        errors.append(LineError(int(f_line[bad[0]]), "malformed command number"))
    _count_unknown(unknown, f_letter, f_value, f_status, (code < 0) & ~bad_gm)
    # one row per known command; the parameter words of its line go to its row
    kr = np.flatnonzero(code >= 0)
    r_line, r_code = f_line[kr], code[kr].astype(np.int64)
    k = len(kr)
    line_to_row = np.full(lx.n_lines, -1, np.int64)
    line_to_row[r_line] = np.arange(k)
    w_row = line_to_row[lx.word_line]
    param_word = (w_row >= 0) & ~lx.word_first
    _word_errors(lx, w_row, param_word, r_code, line_to_row, errors)
    col = COL[lx.word_letter]
    sel = param_word & (col >= 0)
    par = np.full((k, len(PARAMS)), np.nan)
    has = np.zeros((k, len(PARAMS)), bool)
    flat = w_row[sel] * len(PARAMS) + col[sel]
    vals = lx.word_value[sel]
    par.ravel()[flat] = vals
    has.ravel()[flat] = True
    big = np.flatnonzero(np.abs(vals) > MAX_ABS_VALUE)
    if len(big):
        errors.append(LineError(int(lx.word_line[sel][big[0]]), f"value out of range (|v| > {MAX_ABS_VALUE:g})"))
    return CommandTable(r_line, r_code, par, has)


def _count_unknown(unknown: dict[str, int], letter: np.ndarray, value: np.ndarray, status: np.ndarray,
                   is_unknown: np.ndarray) -> None:
    u = np.flatnonzero(is_unknown)
    if len(u) == 0:
        return
    keys = np.stack([letter[u].astype(np.float64), np.where(status[u] == W_OK, value[u], np.nan)], 1)
    distinct, counts = np.unique(keys, axis=0, return_counts=True)
    for (let, val), n in zip(distinct, counts, strict=True):
        name = chr(int(let))
        if np.isfinite(val):
            name += str(int(val)) if val == int(val) and abs(val) < 1e15 else f"{val:g}"
        unknown[name] = unknown.get(name, 0) + int(n)


def _repeated_letter_lines(lx: Lexed) -> np.ndarray:
    """Lines where a letter occurs in two words (``G1 X1 X2``, two E words, ``G90 G21``).

    Per line, the sum of one bit per word's letter equals the OR of those bits
    exactly when no letter repeats (a repeat carries into a higher bit).
    """
    if len(lx.word_line) == 0:
        return lx.word_line
    starts = np.flatnonzero(lx.word_first)
    bits = np.left_shift(np.int64(1), (lx.word_letter.astype(np.int64) - ord("A")) & 31)
    total = np.add.reduceat(bits, starts)
    union = np.bitwise_or.reduceat(bits, starts)
    return lx.word_line[starts[total != union]]


def _word_errors(lx: Lexed, w_row: np.ndarray, param_word: np.ndarray, r_code: np.ndarray,
                 line_to_row: np.ndarray, errors: list[LineError]) -> None:
    """Malformed or empty parameter words; orphan text, bad checksums, exponents and repeated letters on
    command lines."""
    st = lx.word_status
    bad = np.flatnonzero(param_word & (st == W_BAD))
    if len(bad):
        errors.append(LineError(int(lx.word_line[bad[0]]), f"malformed number after {chr(lx.word_letter[bad[0]])}"))
    empty = param_word & (st == W_EMPTY)
    if empty.any():
        flags = np.isin(r_code[np.maximum(w_row, 0)], list(FLAG_OK))
        e = np.flatnonzero(empty & ~flags)
        if len(e):
            errors.append(LineError(int(lx.word_line[e[0]]), f"{chr(lx.word_letter[e[0]])} has no value"))
    for lines, message in ((lx.orphan_lines, "unexpected text (a number with no letter)"),
                           (lx.checksum_bad_lines, "checksum mismatch"),
                           (lx.exponent_lines, "a number in exponent form, or an E word with no blank before it "
                                               "(write 'X1 E30', numbers as plain decimals)")):
        hit = lines[line_to_row[lines] >= 0] if len(lines) else lines
        if len(hit):
            errors.append(LineError(int(hit[0]), message))
    repeated = _repeated_letter_lines(lx)
    repeated = repeated[line_to_row[repeated] >= 0] if len(repeated) else repeated
    if len(repeated):
        ln = int(repeated[0])
        letters, counts = np.unique(lx.word_letter[lx.word_line == ln], return_counts=True)
        errors.append(LineError(ln, f"{chr(letters[counts > 1][0])} appears twice on the line "
                                    "(one value per letter, one command per line)"))
