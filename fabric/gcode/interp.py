"""G-code interpreter: streams blocks of lines through the lexer and resolves modal state.

Per block, every known command becomes one row of a command table
(``table.py``: NaN = word absent) and the modal state is resolved with
cumulative array ops (``modal.py``) instead of a loop over lines:

* modes (G20/G21 units, G90/G91, M82/M83) and the feed rate are forward-filled;
* positions use an anchored cumulative sum per axis: an absolute move or a
  G92 sets the logical coordinate (an anchor), relative moves add to it. A G92
  also shifts the axis offset by ``(logical before - new value)`` so the
  machine position ``logical + offset`` does not jump; G28 resets both to zero;
* the state at the end of a block (position, modes, feed; layer and feature in
  ``layers.py``) is carried into the next block, so memory is bounded by the
  block size plus the output arrays.

The multi-axis dialect (``multiaxis=True``: curved layers, ``docs/protocol.md``)
adds the nozzle axis: on G0/G1, I J K are the axis (from the tip up the
nozzle), modal per letter like X Y Z, normalised per row; a zero vector and
arcs (where I J would be centre offsets) are errors naming their line. A move
that only turns the axis (no X Y Z change) turns it for the moves after it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fabric.gcode import arcs
from fabric.gcode.commands import KNOWN, LENGTH_COLS, PARAMS
from fabric.gcode.events import ExtrudeOnly, command_events
from fabric.gcode.layers import LayerTracker
from fabric.gcode.lexer import Lexed, lex_block
from fabric.gcode.modal import anchored, ffill, modal_setting, shifted
from fabric.gcode.table import CommandTable, LineError, command_table
from fabric.gcode.toolpath import RowColumns, Toolpath
from fabric.wire.errors import GcodeError

__all__ = ["Interpreter", "LexedBlock", "lex_and_tabulate", "DEFAULT_FEED_MM_S"]

DEFAULT_FEED_MM_S = 25.0     # feed before the first F word (Marlin's 1500 mm/min)
_G = dict(KNOWN)
X, Y, Z, E, F, I, J, R, P, S, L, K = range(len(PARAMS))     # noqa: E741  (G-code's own parameter letters)
_G3 = _G["G3"]                 # G0, G1, G2, G3 are the first four codes: motion is ``code <= _G3``
_EVENT_COLUMNS = ("ev_row", "ev_kind", "ev_value", "ev_aux", "ev_line")


@dataclass
class LexedBlock:
    """A block lexed into its command table: the stateless first stage of :meth:`Interpreter.feed`, which
    a worker thread can run for the next block while the interpreter resolves this one."""

    block: bytes | memoryview
    lx: Lexed
    table: CommandTable
    errors: list[LineError]        # malformed commands found so far (the later stages add theirs)
    unknown: dict[str, int]        # unknown commands and their counts


def lex_and_tabulate(block: bytes | memoryview) -> LexedBlock:
    """Lex one block of whole lines and build its command table (no modal state: any thread, any order)."""
    lx = lex_block(block)
    errors: list[LineError] = []
    unknown: dict[str, int] = {}
    table = command_table(lx, errors, unknown)
    return LexedBlock(block, lx, table, errors, unknown)


@dataclass
class _State:
    """What one block leaves to the next: modes, feed, logical position and offset (X, Y, Z, E), counts."""

    unit_mm: float = 1.0
    axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))     # I J K (multi-axis)
    abs_xyz: float = 1.0
    abs_e: float = 1.0
    feed_mm_s: float = DEFAULT_FEED_MM_S
    logical: np.ndarray = field(default_factory=lambda: np.zeros(4))
    offset: np.ndarray = field(default_factory=lambda: np.zeros(4))
    rows: int = 0
    lines: int = 0


@dataclass
class _Modes:
    """Modal settings of each command row of a block (a plain float when the block never changes one)."""

    unit_mm: np.ndarray | float
    abs_xyz: np.ndarray | float
    abs_e: np.ndarray | float
    feed_mm_s: np.ndarray


@dataclass
class _Resets:
    """The G92 (set position) and G28 (home) rows of a block, and those naming no axis (all axes)."""

    g92: np.ndarray
    g28: np.ndarray
    g92_all: np.ndarray
    g28_all: np.ndarray

    @property
    def none(self) -> bool:
        return not (self.g92.any() or self.g28.any())


@dataclass
class _Positions:
    """Machine positions of a block: before row 0, then after each row."""

    machine: np.ndarray        # (4, k + 1) X, Y, Z, E
    e_move: np.ndarray         # (k,) filament each row moves


@dataclass
class _MotionRows:
    """Toolpath rows of a block's motion commands, and its extruder-only moves."""

    rows: dict[str, np.ndarray]    # xyz, e, feed, line
    eonly: ExtrudeOnly


class Interpreter:
    """Feed blocks of whole lines with :meth:`feed`, then take the :class:`Toolpath` from :meth:`finish`."""

    def __init__(self, chord_tol_mm: float = 0.01, rows_hint: int = 0,   # rows_hint: a capacity
                 multiaxis: bool = False) -> None:
        self.chord_tol_mm = float(chord_tol_mm)
        self.multiaxis = bool(multiaxis)
        self.state = _State()
        self.layers = LayerTracker()
        spec: dict[str, tuple[str, tuple[int, ...]]] = {
            "xyz": ("f8", (3,)), "e": ("f8", ()), "feed": ("f8", ()), "line": ("i8", ()), "layer": ("i4", ()),
            "feature": ("i2", ())}
        if self.multiaxis:
            spec["axis"] = ("f8", (3,))
        self._rows = RowColumns(spec, rows_hint)
        self._out: dict[str, list[np.ndarray]] = {k: [] for k in _EVENT_COLUMNS}
        self._unknown: dict[str, int] = {}
        self._start: np.ndarray | None = None
        self._chunks = _Chunks()

    # -- one block ---------------------------------------------------------

    def feed(self, block: bytes | memoryview) -> None:
        """Interpret one block of whole lines (the last line may lack its newline)."""
        self.feed_lexed(lex_and_tabulate(block))

    def feed_lexed(self, lexed: LexedBlock) -> None:
        """Interpret the next block, lexed by :func:`lex_and_tabulate` (blocks in file order)."""
        block, lx, table, errors = lexed.block, lexed.lx, lexed.table, lexed.errors
        st = self.state
        for name, count in lexed.unknown.items():
            self._unknown[name] = self._unknown.get(name, 0) + count
        self._raise_first(block, lx, errors)
        modes = self._modes(table, errors)
        positions = self._positions(table, modes)
        motion = self._motion_rows(table, positions, modes.feed_mm_s, errors)
        rows = motion.rows
        events = self._events(table, rows["line"], motion.eonly, errors)
        self._raise_first(block, lx, errors)
        marked = self.layers.mark(block, lx, rows["line"], st.rows)
        rows["layer"], rows["feature"] = marked.layer, marked.feature
        rows["line"] = st.lines + rows["line"] + 1
        st.rows += len(rows["line"])
        st.lines += lx.n_lines
        self._rows.append(rows)
        for name, arr in events.items():
            self._out[name].append(arr)

    def _raise_first(self, block: bytes | memoryview, lx: Lexed, errors: list[LineError]) -> None:
        """Raise the error of the earliest line, with its text (nothing when there is none)."""
        if not errors:
            return
        first = min(errors, key=lambda err: err.line)
        ln = first.line
        stop = lx.line_start[ln + 1] if ln + 1 < lx.n_lines else len(block)
        text = bytes(block[lx.line_start[ln]:stop]).decode("utf-8", "replace").strip()[:200]
        raise GcodeError(f"{first.message}: {text!r}", line=self.state.lines + ln + 1, text=text)

    # -- modal state -------------------------------------------------------

    def _modes(self, table: CommandTable, errors: list[LineError]) -> _Modes:
        """Units (scaling the length columns of inch rows to mm), distance modes and feed of every row."""
        st, g, code, par = self.state, _G, table.code, table.par
        unit = modal_setting(code, (g["G20"],), (g["G21"],), st.unit_mm, 25.4, 1.0)
        if np.any(unit != 1.0):                     # inches somewhere in the block
            par[:, LENGTH_COLS] *= unit[:, None] if isinstance(unit, np.ndarray) else unit
        abs_xyz = modal_setting(code, (g["G90"],), (g["G91"],), st.abs_xyz)
        abs_e = modal_setting(code, (g["G90"], g["M82"]), (g["G91"], g["M83"]), st.abs_e)
        feed_set = (code <= _G3) & table.has[:, F]
        bad_feed = np.flatnonzero(feed_set & ~(par[:, F] > 0))
        if len(bad_feed):
            errors.append(LineError(int(table.line[bad_feed[0]]), "feed rate F must be positive"))
        feed = ffill(par[:, F] / 60.0, feed_set, st.feed_mm_s)
        if len(code):
            st.feed_mm_s = feed[-1]
            st.unit_mm, st.abs_xyz, st.abs_e = (float(m[-1]) if isinstance(m, np.ndarray) else m
                                                for m in (unit, abs_xyz, abs_e))
        return _Modes(unit, abs_xyz, abs_e, feed)

    def _positions(self, table: CommandTable, modes: _Modes) -> _Positions:
        """Machine positions of X, Y, Z, E after every row, and the filament each row moves."""
        st, code, has = self.state, table.code, table.has
        g92, g28 = code == _G["G92"], code == _G["G28"]
        resets = _Resets(g92, g28, g92 & ~has[:, [X, Y, Z, E]].any(axis=1), g28 & ~has[:, [X, Y, Z]].any(axis=1))
        machine = np.empty((4, len(code) + 1))
        machine[:, 0] = st.logical + st.offset
        e_move = np.zeros(len(code))
        for a in range(4):
            e = self._axis(a, table, modes.abs_e if a == E else modes.abs_xyz, resets, machine[a, 1:])
            if e is not None:
                e_move = e
        return _Positions(machine, e_move)

    def _axis(self, a: int, table: CommandTable, mode: np.ndarray | float, resets: _Resets,
              out: np.ndarray) -> np.ndarray | None:
        """Machine coordinate of axis ``a`` after every row into ``out``; for E, returns the filament
        each row moves. Carries the axis' logical value and offset into the state."""
        st = self.state
        v, h = table.par[:, a], table.has[:, a]
        moved = (table.code <= _G3) & h
        init = st.logical[a]
        offset = None
        e_move = None
        if resets.none and np.ndim(mode) == 0:      # one distance mode, no G92 / G28: the common case
            if mode:                                # absolute: the last programmed value
                logical = ffill(v, moved, init)
                if a == E:
                    e_move = np.where(moved, v - shifted(logical, init), 0.0)
            else:                                   # relative: a running sum
                delta = np.where(moved, v, 0.0)
                logical = init + np.cumsum(delta)
                if a == E:
                    e_move = delta
            out[:] = logical + st.offset[a]
        else:
            set_pos = resets.g92 & (h | resets.g92_all)
            home = resets.g28 & (h | resets.g28_all) if a != E else np.zeros_like(resets.g28)
            rel = moved & (mode == 0)
            anchor = (moved & ~rel) | set_pos | home
            value = np.where(h, v, 0.0)
            anchor_value = np.where(home | (set_pos & ~h), 0.0, value)
            if rel.any():
                logical = anchored(anchor, anchor_value, np.where(rel, value, 0.0), init)
            else:                                   # absolute only: a forward fill is enough
                logical = ffill(anchor_value, anchor, init)
            before = shifted(logical, init)
            if set_pos.any() or home.any():
                offset = anchored(home, np.zeros(len(home)), np.where(set_pos, before - anchor_value, 0.0),
                                  st.offset[a])
                out[:] = logical + offset
            else:                                   # no G92 / G28 on this axis: the offset holds
                out[:] = logical + st.offset[a]
            if a == E:
                e_move = np.where(moved, np.where(rel, value, anchor_value - before), 0.0)
        if len(v):
            st.logical[a] = logical[-1]
            if offset is not None:
                st.offset[a] = offset[-1]
        return e_move

    # -- rows and events ---------------------------------------------------

    def _motion_rows(self, table: CommandTable, positions: _Positions, feed: np.ndarray,
                     errors: list[LineError]) -> _MotionRows:
        """Toolpath rows of the motion commands (arcs expanded into chords).

        Masks run over all k command rows (non-motion rows neither move nor
        extrude), so no gather of the motion rows is needed.
        """
        code, line, e_move = table.code, table.line, positions.e_move
        s, e = positions.machine[:3, :-1], positions.machine[:3, 1:]       # (3, k) start and end points
        lin = code <= _G["G1"]
        moved = (e[0] != s[0]) | (e[1] != s[1]) | (e[2] != s[2])
        lin_row = lin & moved
        eonly = lin & ~moved & (e_move != 0)
        count = lin_row.astype(np.int64)
        arc = np.flatnonzero((code > _G["G1"]) & (code <= _G3))
        chords = None
        if len(arc):
            chords = arcs.expand_arcs(np.ascontiguousarray(s[:, arc].T), np.ascontiguousarray(e[:, arc].T),
                                      code[arc] == _G["G2"], table.par[arc][:, [I, J]], table.par[arc, R],
                                      e_move[arc], self.chord_tol_mm)
            bad = np.flatnonzero(chords.status)
            if len(bad):
                errors.append(LineError(int(line[arc[bad[0]]]), arcs.ARC_REASONS[int(chords.status[bad[0]])]))
            count[arc] = chords.n_points
        total = int(count.sum())
        if chords is None:                          # straight moves only: one row per moving move
            xyz, e_rows = e[:, lin_row].T, e_move[lin_row]
        else:                                       # straight rows and chords in line order
            first = np.cumsum(count) - count
            xyz = np.empty((total, 3))
            e_rows = np.empty(total)
            xyz[first[lin_row]] = e[:, lin_row].T
            e_rows[first[lin_row]] = e_move[lin_row]
            if total:
                ac = count[arc]
                at = np.repeat(first[arc], ac) + (np.arange(int(ac.sum())) - np.repeat(np.cumsum(ac) - ac, ac))
                xyz[at] = chords.points
                e_rows[at] = chords.e_mm
        if self._start is None and total:
            self._start = s[:, np.flatnonzero(count)[0]].copy()
        rows = {"xyz": xyz, "e": e_rows, "feed": np.repeat(feed, count), "line": np.repeat(line, count)}
        if self.multiaxis:
            rows["axis"] = self._axes(table, lin, lin_row, arc, errors)
        return _MotionRows(rows, ExtrudeOnly(line[eonly], e_move[eonly]))

    def _axes(self, table: CommandTable, lin: np.ndarray, lin_row: np.ndarray, arc: np.ndarray,
              errors: list[LineError]) -> np.ndarray:
        """The unit nozzle axis (I J K, modal per letter) of the block's moving G0/G1 rows (multi-axis dialect)."""
        st = self.state
        if len(arc):
            errors.append(LineError(int(table.line[arc[0]]), "an arc (G2/G3) in the multi-axis dialect, where "
                                                             "I J K are the nozzle axis: write arcs as G1 moves"))
        raw = np.empty((len(table.code), 3))
        for k, c in enumerate((I, J, K)):
            raw[:, k] = ffill(table.par[:, c], lin & table.has[:, c], st.axis[k])
        if len(raw):
            st.axis = raw[-1].copy()
        ax = raw[lin_row]
        norm = np.sqrt(np.einsum("ij,ij->i", ax, ax))
        zero = np.flatnonzero(~(norm > 1e-9))
        if len(zero):
            errors.append(LineError(int(table.line[lin_row][zero[0]]),
                                    "the nozzle axis I J K is the zero vector (it must point up the nozzle)"))
            norm[zero] = 1.0
        return ax / norm[:, None]

    def _events(self, table: CommandTable, row_line: np.ndarray, eonly: ExtrudeOnly,
                errors: list[LineError]) -> dict[str, np.ndarray]:
        """Event columns of the block's non-motion commands, attached to the next toolpath row."""
        ev = command_events(table.rows(np.flatnonzero(table.code > _G3)), eonly, errors)
        if ev.n_cnc:
            self._unknown["G10"] = self._unknown.get("G10", 0) + ev.n_cnc
        st = self.state
        return {"ev_row": st.rows + np.searchsorted(row_line, ev.line, side="left"),
                "ev_kind": ev.kind, "ev_value": ev.value, "ev_aux": ev.aux, "ev_line": st.lines + ev.line + 1}

    # -- result in chunks ---------------------------------------------------

    def take_chunk(self, min_rows: int, final: bool = False) -> Toolpath | None:
        """The rows interpreted so far up to a *safe cut* as a toolpath of their own, once there are at least
        ``min_rows`` (``final``: all the rows left, the file being at its end); None while there is no cut.

        A safe cut lies between two rows that both extrude (filament fed while moving), with no event
        between them: no travel run, lift or stop straddles it, so the chunks plan exactly as the whole
        toolpath would (``fabric.planning.planner``). Each chunk starts where the last one ended
        (``start_xyz_mm``); its event rows are its own. Layers: from the markers as they come, or inferred
        from Z across chunks as :func:`~fabric.gcode.layers.infer_layers` does on the whole file, when the
        file has shown no marker by its first chunk. ``layer_z_mm`` of a chunk is empty: the layers of the
        whole file are in :meth:`chunk_summary` once the last chunk is taken.
        """
        ch = self._chunks
        n = self._rows.n
        if not final and n < max(min_rows, 2):
            return None
        cols = self._rows.cols
        ev = {k: (np.concatenate(v) if len(v) > 1 else v[0]) if v else np.zeros(0) for k, v in self._out.items()}
        for k, arr in ev.items():
            self._out[k] = [arr] if len(arr) else []
        ev_row = ev["ev_row"].astype(np.int64, copy=False) - ch.base if len(ev["ev_row"]) else np.zeros(0, np.int64)
        if final:
            c = n
        else:
            c = _safe_cut(cols["xyz"][:n], cols["e"][:n], ev_row, max(min_rows, 2))
            if c <= 0:
                return None
        if ch.infer is None:
            ch.infer = self.layers.layer_count == 0
        start = ch.last_xyz if ch.last_xyz is not None else self._start
        if start is None:
            start = self.state.logical[:3] + self.state.offset[:3]
        xyz, e = cols["xyz"][:c].copy(), cols["e"][:c].copy()
        layer = ch.infer_layers(xyz, e) if ch.infer else cols["layer"][:c].copy()
        if not ch.infer:
            ch.first_extruding_z(xyz, e, layer)
        sel = ev_row < c if not final else np.ones(len(ev_row), bool)
        tp = Toolpath(
            start_xyz_mm=np.array(start, dtype=float), xyz_mm=xyz, e_mm=e, feed_mm_s=cols["feed"][:c].copy(),
            line=cols["line"][:c].copy(), layer=layer.astype(np.int32, copy=False),
            feature=cols["feature"][:c].copy(), feature_names=list(self.layers.features),
            event_row=ev_row[sel], event_kind=ev["ev_kind"][sel].astype("u1", copy=False),
            event_value=ev["ev_value"][sel].astype("f8", copy=False),
            event_aux=ev["ev_aux"][sel].astype("i2", copy=False),
            event_line=ev["ev_line"][sel].astype("i8", copy=False), layer_z_mm=np.zeros(0),
            unknown_commands={}, n_lines=self.state.lines,
            axis=cols["axis"][:c].copy() if self.multiaxis else None)
        if c:
            ch.last_xyz = xyz[-1].copy()
        # the rest moves to the front of the columns; the events left keep their rows (relative to the new base)
        for arr in cols.values():
            arr[:n - c] = arr[c:n]
        self._rows.n = n - c
        ch.base += c
        for k in self._out:
            left = ev[k][~sel] if len(ev[k]) else ev[k]
            self._out[k] = [left] if len(left) else []
        return tp

    def chunk_summary(self) -> ChunkSummary:
        """What the whole file held, once its last chunk is taken: lines, layers and their Z, unknown commands."""
        ch = self._chunks
        if ch.infer is None or ch.infer:
            layer_z = np.asarray(ch.layer_z, dtype=float)
        else:
            layer_z = np.full(self.layers.layer_count, np.nan)
            for li, z in ch.first_z.items():
                if li < len(layer_z):
                    layer_z[li] = z
            for li, z in self.layers.layer_z.items():
                layer_z[li] = z
        return ChunkSummary(n_lines=self.state.lines, n_rows=ch.base + self._rows.n, layer_z_mm=layer_z,
                            unknown_commands=dict(sorted(self._unknown.items())),
                            feature_names=list(self.layers.features))

    # -- result ------------------------------------------------------------

    def finish(self) -> Toolpath:
        """The whole toolpath (layers inferred from Z when the file has no layer markers)."""
        o = self._out

        def cat(name: str, dtype: str, *shape: int) -> np.ndarray:
            return np.concatenate(o[name]).astype(dtype, copy=False) if o[name] else np.zeros((0, *shape), dtype)

        rows = self._rows.take()
        xyz, e = rows["xyz"], rows["e"]
        layers = self.layers.layers(xyz, e, rows["layer"])
        end = self.state.logical[:3] + self.state.offset[:3]
        return Toolpath(
            start_xyz_mm=self._start if self._start is not None else end.copy(),
            xyz_mm=xyz, e_mm=e, feed_mm_s=rows["feed"], line=rows["line"],
            layer=layers.layer.astype(np.int32, copy=False), feature=rows["feature"],
            feature_names=list(self.layers.features), event_row=cat("ev_row", "i8"),
            event_kind=cat("ev_kind", "u1"), event_value=cat("ev_value", "f8"),
            event_aux=cat("ev_aux", "i2"), event_line=cat("ev_line", "i8"),
            layer_z_mm=layers.layer_z_mm, unknown_commands=dict(sorted(self._unknown.items())),
            n_lines=self.state.lines, axis=rows["axis"] if self.multiaxis else None)


@dataclass
class ChunkSummary:
    """The whole file, after its chunks (:meth:`Interpreter.take_chunk`)."""

    n_lines: int
    n_rows: int
    layer_z_mm: np.ndarray
    unknown_commands: dict[str, int]
    feature_names: list[str]

    @property
    def n_layers(self) -> int:
        return len(self.layer_z_mm)


@dataclass
class _Chunks:
    """What one chunk leaves to the next: where the rows left start, the last point, the layer inference."""

    base: int = 0                               # the toolpath row of the first row not yet taken
    last_xyz: np.ndarray | None = None
    infer: bool | None = None                   # layers inferred from Z (decided at the first chunk)
    layer_z: list[float] = field(default_factory=list)      # inferred: Z of each layer so far
    z_max: float = -np.inf                      # inferred: the highest extruding row so far
    first_z: dict[int, float] = field(default_factory=dict)   # markers: Z of each layer's first extruding row

    def infer_layers(self, xyz: np.ndarray, e: np.ndarray) -> np.ndarray:
        """Layers of a chunk's rows from Z, continuing the chunks before (as ``infer_layers`` on the whole)."""
        n = len(e)
        before = len(self.layer_z) - 1
        ext = np.flatnonzero(e > 0)
        if len(ext) == 0:
            return np.full(n, before, np.int32)
        z = xyz[ext, 2]
        prev = np.maximum.accumulate(np.concatenate([[self.z_max], z[:-1]]))
        new = z > prev + 1e-6
        ni = np.flatnonzero(new)
        # a layer begins right after the previous extruding row: the row before this chunk's first one
        # extruded (the cut is between extruding rows), so a new layer at ext[0] begins at row 0 of the chunk
        first = ext[0] if not np.isfinite(self.z_max) else 0
        starts = np.where(ni == 0, first, ext[np.maximum(ni - 1, 0)] + 1)
        layer = before + np.searchsorted(starts, np.arange(n), side="right")
        self.layer_z.extend(z[ni].tolist())
        self.z_max = max(self.z_max, float(z.max()))
        return layer.astype(np.int32)

    def first_extruding_z(self, xyz: np.ndarray, e: np.ndarray, layer: np.ndarray) -> None:
        """Markers: the Z of the first extruding row of each layer not seen before (its default Z)."""
        ext = np.flatnonzero((e > 0) & (layer >= 0))
        if len(ext) == 0:
            return
        u, first = np.unique(layer[ext], return_index=True)
        for li, k in zip(u.tolist(), first.tolist(), strict=True):
            self.first_z.setdefault(int(li), float(xyz[ext[k], 2]))


def _safe_cut(xyz: np.ndarray, e: np.ndarray, ev_row: np.ndarray, limit: int) -> int:
    """A row ``c`` (``2 <= c < n``) such that rows ``c - 1`` and ``c`` both extrude (filament fed while moving
    more than 1e-9 mm) with no event at row ``c``: the last one at most ``limit``, else the first one after it;
    0 if there is none."""
    n = len(e)
    if n < 3:
        return 0
    d = xyz[1:] - xyz[:-1]
    ext = (e[1:] > 0) & (np.einsum("ij,ij->i", d, d) > 1e-18)         # rows 1 .. n-1
    ok = ext[1:] & ext[:-1]                                           # c = 2 .. n-1
    if len(ev_row):
        at = ev_row[(ev_row >= 2) & (ev_row < n)]
        ok[at - 2] = False
    hit = np.flatnonzero(ok) + 2
    if len(hit) == 0:
        return 0
    k = int(np.searchsorted(hit, limit, side="right"))
    return int(hit[k - 1]) if k > 0 else int(hit[0])
