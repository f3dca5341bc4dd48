"""G-code interpreter: streams blocks of lines through the lexer and resolves modal state.

Per block, every known command becomes one row of a parameter table (NaN =
word absent) and the modal state is resolved with cumulative array ops instead
of a loop over lines:

* modes (G20/G21 units, G90/G91, M82/M83) and the feed rate are
  *forward-filled*: the index of the last row that set them, carried with
  ``maximum.accumulate``;
* positions use an *anchored cumulative sum* per axis: an absolute move or a
  G92 sets the logical coordinate (an anchor), relative moves add to it, so the
  value after row ``k`` is ``anchor + (cumsum[k] - cumsum[anchor])``. A G92
  also shifts the axis offset by ``(logical before - new value)`` so the machine
  position ``logical + offset`` does not jump; G28 resets both to zero;
* the state at the end of a block (position, modes, feed, layer, feature) is
  carried into the next block, so memory is bounded by the block size plus the
  output arrays.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fabric.errors import GcodeError
from fabric.gcode import arcs
from fabric.gcode.commands import COL, FLAG_OK, KNOWN, LENGTH_COLS, PARAMS, code_of
from fabric.gcode.dialects import MK_FEATURE, MK_LAYER, MK_Z, find_markers
from fabric.gcode.lexer import W_BAD, W_EMPTY, W_OK, Lexed, lex_block
from fabric.gcode.events import command_events
from fabric.gcode.toolpath import RowColumns, Toolpath

__all__ = ["Interpreter", "DEFAULT_FEED_MM_S"]

DEFAULT_FEED_MM_S = 25.0     # feed before the first F word (Marlin's 1500 mm/min)
MAX_ABS_VALUE = 1e9          # any parameter beyond this (mm, mm/min, deg C...) is an error
_G = {name: code for name, code in KNOWN.items()}
X, Y, Z, E, F, I, J, R, P, S, L = range(len(PARAMS))
_G3 = _G["G3"]                 # G0, G1, G2, G3 are the first four codes: motion is ``code <= _G3``


def _ffill(values: np.ndarray, present: np.ndarray, init: float) -> np.ndarray:
    """Value of the last row at or before each row where ``present`` (``init`` before any)."""
    idx = np.where(present, np.arange(len(values)), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, values[np.maximum(idx, 0)], init)


def _anchored(anchor: np.ndarray, anchor_val: np.ndarray, delta: np.ndarray, init: float) -> np.ndarray:
    """Running value: reset to ``anchor_val`` at anchors, plus ``delta`` elsewhere."""
    c = np.cumsum(np.where(anchor, 0.0, delta))
    a = np.where(anchor, np.arange(len(anchor)), -1)
    np.maximum.accumulate(a, out=a)
    ai = np.maximum(a, 0)
    return np.where(a >= 0, anchor_val[ai] + (c - c[ai]), init + c)


def _shift(after: np.ndarray, init: float) -> np.ndarray:
    return np.concatenate([[init], after[:-1]])


def _modal(r_code: np.ndarray, on: tuple[int, ...], off: tuple[int, ...], init: float,
           on_val: float = 1.0, off_val: float = 0.0) -> np.ndarray | float:
    """A modal setting per row (``on_val`` after an ``on`` code, ``off_val`` after an ``off`` one),
    forward-filled from ``init``; just ``init`` when the block never sets it."""
    is_on = np.zeros(len(r_code), bool)
    is_off = np.zeros(len(r_code), bool)
    for c in on:
        is_on |= r_code == c
    for c in off:
        is_off |= r_code == c
    setting = is_on | is_off
    if not setting.any():
        return init
    return _ffill(np.where(is_on, on_val, off_val), setting, init)


@dataclass
class _State:
    unit_mm: float = 1.0
    abs_xyz: float = 1.0
    abs_e: float = 1.0
    feed_mm_s: float = DEFAULT_FEED_MM_S
    logical: np.ndarray = field(default_factory=lambda: np.zeros(4))
    offset: np.ndarray = field(default_factory=lambda: np.zeros(4))
    rows: int = 0
    lines: int = 0
    layer_count: int = 0
    last_marker_row: int = -1
    feature: int = 0


class Interpreter:
    """Feed blocks of whole lines with :meth:`feed`, then take the :class:`Toolpath` from :meth:`finish`."""

    def __init__(self, chord_tol_mm: float = 0.01, rows_hint: int = 0) -> None:   # rows_hint: a capacity
        self.chord_tol_mm = float(chord_tol_mm)
        self.state = _State()
        self._rows = RowColumns({"xyz": ("f8", (3,)), "e": ("f8", ()), "feed": ("f8", ()), "line": ("i8", ()),
                                 "layer": ("i4", ()), "feature": ("i2", ())}, rows_hint)
        self._out: dict[str, list[np.ndarray]] = {k: [] for k in ("ev_row", "ev_kind", "ev_value", "ev_aux", "ev_line")}
        self._layer_z: dict[int, float] = {}
        self._features: dict[str, int] = {"none": 0}
        self._unknown: dict[str, int] = {}
        self._start: np.ndarray | None = None

    # -- errors ------------------------------------------------------------

    def _raise_first(self, block: bytes | memoryview, lx: Lexed, errors: list[tuple[int, str]]) -> None:
        if not errors:
            return
        ln, message = min(errors, key=lambda t: t[0])
        stop = lx.line_start[ln + 1] if ln + 1 < lx.n_lines else len(block)
        text = bytes(block[lx.line_start[ln]:stop]).decode("utf-8", "replace").strip()[:200]
        raise GcodeError(f"{message}: {text!r}", line=self.state.lines + ln + 1, text=text)

    # -- one block ---------------------------------------------------------

    def feed(self, block: bytes | memoryview) -> None:
        """Interpret one block of whole lines (the last line may lack its newline)."""
        lx = lex_block(block)
        st = self.state
        errors: list[tuple[int, str]] = []
        wf = np.flatnonzero(lx.word_first)
        f_letter, f_value = lx.word_letter[wf], lx.word_value[wf]
        f_status, f_line = lx.word_status[wf], lx.word_line[wf]
        code = code_of(f_letter, f_value, f_status == W_OK)
        gm = (f_letter == ord("G")) | (f_letter == ord("M"))
        bad = np.flatnonzero(gm & (f_status == W_BAD))
        if len(bad):
            errors.append((int(f_line[bad[0]]), "malformed command number"))
        self._count_unknown(f_letter, f_value, f_status, (code < 0) & ~(gm & (f_status == W_BAD)))
        kr = np.flatnonzero(code >= 0)
        r_line, r_code = f_line[kr], code[kr].astype(np.int64)
        k = len(kr)
        l2r = np.full(lx.n_lines, -1, np.int64)
        l2r[r_line] = np.arange(k)
        w_row = l2r[lx.word_line]
        pw = (w_row >= 0) & ~lx.word_first
        self._word_errors(lx, w_row, pw, r_code, l2r, errors)
        col = COL[lx.word_letter]
        sel = pw & (col >= 0)
        par = np.full((k, len(PARAMS)), np.nan)
        has = np.zeros((k, len(PARAMS)), bool)
        flat = w_row[sel] * len(PARAMS) + col[sel]
        vals = lx.word_value[sel]
        par.ravel()[flat] = vals
        has.ravel()[flat] = True
        big = np.flatnonzero(np.abs(vals) > MAX_ABS_VALUE)
        if len(big):
            errors.append((int(lx.word_line[sel][big[0]]), f"value out of range (|v| > {MAX_ABS_VALUE:g})"))
        self._raise_first(block, lx, errors)
        rows, events = self._resolve(r_line, r_code, par, has, errors)
        self._raise_first(block, lx, errors)
        self._markers(block, lx, rows)
        rows["line"] = st.lines + rows["line"] + 1
        st.rows += len(rows["line"])
        st.lines += lx.n_lines
        self._rows.append(rows)
        for name, arr in events.items():
            self._out[name].append(arr)

    def _count_unknown(self, letter: np.ndarray, value: np.ndarray, status: np.ndarray,
                       unknown: np.ndarray) -> None:
        u = np.flatnonzero(unknown)
        if len(u) == 0:
            return
        keys = np.stack([letter[u].astype(np.float64), np.where(status[u] == W_OK, value[u], np.nan)], 1)
        uniq, counts = np.unique(keys, axis=0, return_counts=True)
        for (let, val), n in zip(uniq, counts):
            name = chr(int(let))
            if np.isfinite(val):
                name += str(int(val)) if val == int(val) and abs(val) < 1e15 else f"{val:g}"
            self._unknown[name] = self._unknown.get(name, 0) + int(n)

    def _word_errors(self, lx: Lexed, w_row: np.ndarray, pw: np.ndarray, r_code: np.ndarray,
                     l2r: np.ndarray, errors: list[tuple[int, str]]) -> None:
        st = lx.word_status
        bad = np.flatnonzero(pw & (st == W_BAD))
        if len(bad):
            errors.append((int(lx.word_line[bad[0]]), f"malformed number after {chr(lx.word_letter[bad[0]])}"))
        empty = pw & (st == W_EMPTY)
        if empty.any():
            flags = np.isin(r_code[np.maximum(w_row, 0)], list(FLAG_OK))
            e = np.flatnonzero(empty & ~flags)
            if len(e):
                errors.append((int(lx.word_line[e[0]]), f"{chr(lx.word_letter[e[0]])} has no value"))
        for lines, msg in ((lx.orphan_lines, "unexpected text (a number with no letter)"),
                           (lx.checksum_bad_lines, "checksum mismatch")):
            hit = lines[l2r[lines] >= 0] if len(lines) else lines
            if len(hit):
                errors.append((int(hit[0]), msg))

    # -- modal state -------------------------------------------------------

    def _resolve(self, r_line: np.ndarray, r_code: np.ndarray, par: np.ndarray, has: np.ndarray,
                 errors: list[tuple[int, str]]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        st = self.state
        g = _G
        k = len(r_code)
        unit = _modal(r_code, (g["G20"],), (g["G21"],), st.unit_mm, 25.4, 1.0)
        if np.any(unit != 1.0):                     # inches somewhere in the block
            par[:, LENGTH_COLS] *= unit[:, None] if np.ndim(unit) else unit
        absx = _modal(r_code, (g["G90"],), (g["G91"],), st.abs_xyz)
        abse = _modal(r_code, (g["G90"], g["M82"]), (g["G91"], g["M83"]), st.abs_e)
        motion = r_code <= _G3                       # G0..G3 are codes 0..3
        fset = motion & has[:, F]
        badf = np.flatnonzero(fset & ~(par[:, F] > 0))
        if len(badf):
            errors.append((int(r_line[badf[0]]), "feed rate F must be positive"))
        feed = _ffill(par[:, F] / 60.0, fset, st.feed_mm_s)
        g92 = r_code == g["G92"]
        g28 = r_code == g["G28"]
        plain = not (g92.any() or g28.any())
        g92_all = g92 & ~has[:, [X, Y, Z, E]].any(axis=1)
        g28_all = g28 & ~has[:, [X, Y, Z]].any(axis=1)
        pos = np.empty((4, k + 1))                   # machine position before row 0, then after each row
        pos[:, 0] = st.logical + st.offset
        e_move = np.zeros(k)
        for a in range(4):
            v, h = par[:, a], has[:, a]
            mode = abse if a == E else absx
            mv = motion & h
            init = st.logical[a]
            off = None
            if plain and np.ndim(mode) == 0:         # one distance mode, no G92 / G28: the common case
                if mode:                             # absolute: the last programmed value
                    lg = _ffill(v, mv, init)
                    if a == E:
                        e_move = np.where(mv, v - _shift(lg, init), 0.0)
                else:                                # relative: a running sum
                    delta = np.where(mv, v, 0.0)
                    lg = init + np.cumsum(delta)
                    if a == E:
                        e_move = delta
                pos[a, 1:] = lg + st.offset[a]
            else:
                setp = g92 & (h | g92_all)
                home = g28 & (h | g28_all) if a != E else np.zeros_like(g28)
                rel = mv & (mode == 0)
                anchor = (mv & ~rel) | setp | home
                vz = np.where(h, v, 0.0)
                aval = np.where(home | (setp & ~h), 0.0, vz)
                if rel.any():
                    lg = _anchored(anchor, aval, np.where(rel, vz, 0.0), init)
                else:                                # absolute only: a forward fill is enough
                    lg = _ffill(aval, anchor, init)
                lg_before = _shift(lg, init)
                if setp.any() or home.any():
                    off = _anchored(home, np.zeros(len(home)), np.where(setp, lg_before - aval, 0.0), st.offset[a])
                    pos[a, 1:] = lg + off
                else:                                # no G92 / G28 on this axis: the offset holds
                    pos[a, 1:] = lg + st.offset[a]
                if a == E:
                    e_move = np.where(mv, np.where(rel, vz, aval - lg_before), 0.0)
            if k:
                st.logical[a] = lg[-1]
                if off is not None:
                    st.offset[a] = off[-1]
        if k:
            st.feed_mm_s = feed[-1]
            st.unit_mm, st.abs_xyz, st.abs_e = (float(m[-1]) if np.ndim(m) else m for m in (unit, absx, abse))
        rows, eonly = self._motion_rows(r_line, r_code, par, pos, e_move, feed, errors)
        events = self._events(r_line, r_code, par, has, rows["line"], eonly, errors)
        return rows, events

    def _motion_rows(self, r_line: np.ndarray, r_code: np.ndarray, par: np.ndarray, pos: np.ndarray,
                     e_move: np.ndarray, feed: np.ndarray, errors: list[tuple[int, str]]
                     ) -> tuple[dict[str, np.ndarray], tuple[np.ndarray, np.ndarray]]:
        """Toolpath rows of the motion commands; ``pos`` (4, k + 1) holds the positions before/after rows.

        Masks run over all k command rows (non-motion rows neither move nor extrude), so
        no gather of the motion rows is needed.
        """
        s, e = pos[:3, :-1], pos[:3, 1:]                              # (3, k) start and end points
        lin = r_code <= _G["G1"]
        moved = (e[0] != s[0]) | (e[1] != s[1]) | (e[2] != s[2])
        lin_row = lin & moved
        eonly = lin & ~moved & (e_move != 0)
        count = lin_row.astype(np.int64)
        arc = np.flatnonzero((r_code > _G["G1"]) & (r_code <= _G3))
        if len(arc):
            ac, pts, pe, status = arcs.expand_arcs(
                np.ascontiguousarray(s[:, arc].T), np.ascontiguousarray(e[:, arc].T), r_code[arc] == _G["G2"],
                par[arc][:, [I, J]], par[arc, R], e_move[arc], self.chord_tol_mm)
            badk = np.flatnonzero(status)
            if len(badk):
                errors.append((int(r_line[arc[badk[0]]]), arcs.ARC_REASONS[int(status[badk[0]])]))
            count[arc] = ac
        total = int(count.sum())
        if not len(arc):                             # straight moves only: one row per moving move
            xyz, e_rows = e[:, lin_row].T, e_move[lin_row]
        else:
            first = np.cumsum(count) - count
            xyz = np.empty((total, 3))
            e_rows = np.empty(total)
            xyz[first[lin_row]] = e[:, lin_row].T
            e_rows[first[lin_row]] = e_move[lin_row]
            if total:
                ac = count[arc]
                at = np.repeat(first[arc], ac) + (np.arange(int(ac.sum())) - np.repeat(np.cumsum(ac) - ac, ac))
                xyz[at] = pts
                e_rows[at] = pe
        if self._start is None and total:
            self._start = s[:, np.flatnonzero(count)[0]].copy()
        rows = {"xyz": xyz, "e": e_rows, "feed": np.repeat(feed, count), "line": np.repeat(r_line, count)}
        return rows, (r_line[eonly], e_move[eonly])

    def _events(self, r_line: np.ndarray, r_code: np.ndarray, par: np.ndarray, has: np.ndarray,
                row_line: np.ndarray, eonly: tuple[np.ndarray, np.ndarray],
                errors: list[tuple[int, str]]) -> dict[str, np.ndarray]:
        sub = np.flatnonzero(r_code > _G3)          # the few non-motion commands
        lines, kinds, values, auxs, n_cnc = command_events(r_line[sub], r_code[sub], par[sub], has[sub], eonly, errors)
        if n_cnc:
            self._unknown["G10"] = self._unknown.get("G10", 0) + n_cnc
        st = self.state
        return {"ev_row": st.rows + np.searchsorted(row_line, lines, side="left"),
                "ev_kind": kinds, "ev_value": values, "ev_aux": auxs, "ev_line": st.lines + lines + 1}

    # -- layers and features -----------------------------------------------

    def _markers(self, block: bytes | memoryview, lx: Lexed, rows: dict[str, np.ndarray]) -> None:
        st = self.state
        mk = find_markers(block, lx.line_start, lx.code_end)
        row_line = rows["line"]
        lay = np.flatnonzero(mk.kind == MK_LAYER)
        ml = mk.line[lay]
        mrow = st.rows + np.searchsorted(row_line, ml, side="left")
        new = mrow != np.concatenate([[st.last_marker_row], mrow[:-1]])
        newl = ml[new]
        layer_at = st.layer_count + np.cumsum(new) - 1
        for i in np.flatnonzero(np.isfinite(mk.z_mm[lay])):
            self._layer_z[int(layer_at[i])] = float(mk.z_mm[lay][i])
        zi = np.flatnonzero(mk.kind == MK_Z)
        zl = st.layer_count - 1 + np.searchsorted(newl, mk.line[zi], side="right")
        for layer, z in zip(zl, mk.z_mm[zi]):
            if layer >= 0:
                self._layer_z[int(layer)] = float(z)
        rows["layer"] = (st.layer_count - 1 + np.searchsorted(newl, row_line, side="left")).astype(np.int32)
        st.layer_count += int(new.sum())
        if len(mrow):
            st.last_marker_row = int(mrow[-1])
        fi = np.flatnonzero(mk.kind == MK_FEATURE)
        fcode = np.array([self._features.setdefault(mk.names[i], len(self._features)) for i in fi], np.int16)
        j = np.searchsorted(mk.line[fi], row_line, side="left") - 1
        rows["feature"] = np.where(j >= 0, fcode[np.maximum(j, 0)] if len(fcode) else 0,
                                   st.feature).astype(np.int16)
        if len(fcode):
            st.feature = int(fcode[-1])

    # -- result ------------------------------------------------------------

    def finish(self) -> Toolpath:
        """The whole toolpath (layers inferred from Z when the file has no layer markers)."""
        o = self._out

        def cat(name: str, dtype: str, *shape: int) -> np.ndarray:
            return np.concatenate(o[name]).astype(dtype, copy=False) if o[name] else np.zeros((0, *shape), dtype)

        rows = self._rows.take()
        xyz, e = rows["xyz"], rows["e"]
        if self.state.layer_count == 0:
            layer, layer_z = _infer_layers(xyz, e)
        else:
            layer = rows["layer"]
            layer_z = np.full(self.state.layer_count, np.nan)
            ext = np.flatnonzero((e > 0) & (layer >= 0))
            u, first = np.unique(layer[ext], return_index=True)
            layer_z[u] = xyz[ext[first], 2]
            for li, z in self._layer_z.items():
                layer_z[li] = z
        end = self.state.logical[:3] + self.state.offset[:3]
        return Toolpath(
            start_xyz_mm=self._start if self._start is not None else end.copy(),
            xyz_mm=xyz, e_mm=e, feed_mm_s=rows["feed"], line=rows["line"],
            layer=layer.astype(np.int32, copy=False), feature=rows["feature"],
            feature_names=list(self._features), event_row=cat("ev_row", "i8"),
            event_kind=cat("ev_kind", "u1"), event_value=cat("ev_value", "f8"),
            event_aux=cat("ev_aux", "i2"), event_line=cat("ev_line", "i8"),
            layer_z_mm=layer_z, unknown_commands=dict(sorted(self._unknown.items())),
            n_lines=self.state.lines)


def _infer_layers(xyz: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Layers from Z: a new layer starts when an extruding move is higher than all before it.

    The layer begins right after the previous layer's last extruding move, so
    the travel (and lift) to the new layer belongs to it; rows before the first
    extrusion are layer -1.
    """
    n = len(e)
    ext = np.flatnonzero(e > 0)
    if len(ext) == 0:
        return np.full(n, -1, np.int32), np.zeros(0)
    z = xyz[ext, 2]
    new = np.concatenate([[True], z[1:] > np.maximum.accumulate(z)[:-1] + 1e-6])
    ni = np.flatnonzero(new)
    starts = np.where(ni == 0, ext[0], ext[np.maximum(ni - 1, 0)] + 1)
    layer = np.searchsorted(starts, np.arange(n), side="right") - 1
    return layer.astype(np.int32), z[ni]
