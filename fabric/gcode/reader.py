"""Entry points: G-code text or file -> :class:`Toolpath`, read in blocks of whole lines."""
from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator
from typing import BinaryIO

from fabric.ahead import ordered_map
from fabric.gcode.dialects import detect_slicer
from fabric.gcode.interp import ChunkSummary, Interpreter, LexedBlock, lex_and_tabulate
from fabric.gcode.material import HEAD_BYTES, Material, read_material
from fabric.gcode.toolpath import Toolpath
from fabric.wire.errors import NotFound, ValidationError

__all__ = ["parse_gcode", "parse_gcode_file", "iter_blocks", "ToolpathChunks", "BLOCK_BYTES", "is_multiaxis"]

BLOCK_BYTES = 1 << 19      # ~20k lines (measured fastest with the lexer a block ahead: 0.33 s for 1M moves)
LEX_AHEAD = 2              # blocks lexed by a worker thread ahead of the interpreter


def iter_blocks(stream: BinaryIO, block_bytes: int = BLOCK_BYTES) -> Iterator[bytes]:
    """Blocks of whole lines from a binary stream (each but the last ends with a newline)."""
    rest = b""
    while True:
        chunk = stream.read(block_bytes)
        if not chunk:
            if rest:
                yield rest
            return
        data = rest + chunk if rest else chunk
        cut = data.rfind(b"\n") + 1
        if cut == 0:
            rest = data
            continue
        yield data[:cut]
        rest = data[cut:]


def lexed_blocks(blocks: Iterator[bytes | memoryview]) -> Iterator[LexedBlock]:
    """The blocks lexed into command tables by a worker thread while the caller interprets the one before
    (lexing is stateless; the modal state is resolved in order by the interpreter)."""
    return ordered_map(lex_and_tabulate, blocks, workers=1, ahead=LEX_AHEAD)


def _memory_blocks(data: bytes | bytearray, view: memoryview, block_bytes: int) -> Iterator[memoryview]:
    """Blocks of whole lines of G-code held in memory (views, no copies)."""
    n, pos = len(view), 0
    while pos < n:
        stop = min(pos + block_bytes, n)
        if stop < n:                              # extend to the end of the line
            nl = data.find(b"\n", stop - 1)
            stop = n if nl < 0 else nl + 1
        yield view[pos:stop]
        pos = stop


def _check(chord_tol_mm: float, block_bytes: int) -> None:
    if not (chord_tol_mm > 0):
        raise ValidationError("chord_tol_mm must be > 0", field="chord_tol_mm", value=chord_tol_mm)
    if block_bytes < 1024:
        raise ValidationError("block_bytes must be >= 1024", field="block_bytes", value=block_bytes)


MULTIAXIS_MARK = b"; multiaxis:"          # the first line of the multi-axis dialect (fabric.slicing.curved.gcode)


def is_multiaxis(head: bytes) -> bool:
    """Whether G-code whose first bytes are ``head`` is in the multi-axis dialect (a nozzle axis I J K on every
    move; its first line, or a comment line of the first 4 KiB, is ``; multiaxis: ...``)."""
    head = head[:4096]
    return head.startswith(MULTIAXIS_MARK) or b"\n" + MULTIAXIS_MARK in head


def parse_gcode(source: str | bytes | bytearray | memoryview, *, chord_tol_mm: float = 0.01,
                block_bytes: int = BLOCK_BYTES,
                progress: Callable[[float], None] | None = None) -> Toolpath:
    """Interpret G-code held in memory.

    ``chord_tol_mm`` bounds how far arc chords stray from the arc. ``progress``
    is called with the fraction of bytes done after each block. Raises
    :class:`GcodeError` (with ``line`` and ``text``) on a malformed known command.
    """
    _check(chord_tol_mm, block_bytes)
    if isinstance(source, str):
        data: bytes | bytearray = source.encode("utf-8", "surrogateescape")
    else:
        data = source if isinstance(source, (bytes, bytearray)) else bytes(source)
    view = memoryview(data).cast("B")
    interp = Interpreter(chord_tol_mm, rows_hint=len(data) // 12, multiaxis=is_multiaxis(bytes(view[:4096])))
    n, pos = len(view), 0
    for lexed in lexed_blocks(_memory_blocks(data, view, block_bytes)):
        interp.feed_lexed(lexed)
        pos += len(lexed.block)
        if progress is not None:
            progress(pos / n)
    tp = interp.finish()
    tp.slicer = detect_slicer(bytes(view[:8192]))
    tail = bytes(view[max(n - HEAD_BYTES, HEAD_BYTES):])
    tp.material = read_material(bytes(view[:HEAD_BYTES]), tail, tp.n_lines)
    return tp


def parse_gcode_file(path: str | os.PathLike[str], *, chord_tol_mm: float = 0.01,
                     block_bytes: int = BLOCK_BYTES,
                     progress: Callable[[float], None] | None = None) -> Toolpath:
    """Interpret a G-code file, streaming it in blocks (memory: one block plus the output)."""
    _check(chord_tol_mm, block_bytes)
    try:
        size = os.path.getsize(path)
        stream = open(path, "rb")     # noqa: SIM115  (closed by the with block below)
    except FileNotFoundError as exc:
        raise NotFound(f"G-code file not found: {path}", file=str(path)) from exc
    done = 0
    with stream:
        multiaxis = is_multiaxis(stream.read(4096))
        stream.seek(0)
        interp = Interpreter(chord_tol_mm, rows_hint=size // 12, multiaxis=multiaxis)   # moves take >= ~12 bytes
        for lexed in lexed_blocks(iter_blocks(stream, block_bytes)):
            interp.feed_lexed(lexed)
            done += len(lexed.block)
            if progress is not None:
                progress(done / max(size, 1))
        stream.seek(0)
        head = stream.read(HEAD_BYTES)
        stream.seek(max(size - HEAD_BYTES, len(head)))
        tail = stream.read(HEAD_BYTES)
    tp = interp.finish()
    tp.slicer = detect_slicer(head[:8192])
    tp.material = read_material(head, tail, tp.n_lines)
    return tp


class ToolpathChunks:
    """G-code (text or bytes in memory, or a file named by a path) interpreted in chunks of about ``chunk_rows``
    toolpath rows, so that what holds the rows never holds the whole file's (a 500 MB file is ~17 M rows).

    Iterating gives ``(chunk, last)``: each chunk a :class:`Toolpath` ending at a safe cut
    (:meth:`Interpreter.take_chunk`), ``last`` true for the final one (a chunk is handed over once the
    next one exists, so the caller knows which is last). The slicer and the stated material come from the
    file's first and last bytes, read before the first chunk (:meth:`material`); once the iteration has
    ended, :attr:`summary` holds the lines, layers and unknown commands of the whole file.
    """

    def __init__(self, source: str | bytes | bytearray | memoryview | os.PathLike[str], *, chunk_rows: int,
                 chord_tol_mm: float = 0.01, block_bytes: int = BLOCK_BYTES,
                 progress: Callable[[float], None] | None = None) -> None:
        _check(chord_tol_mm, block_bytes)
        self.chunk_rows, self.chord_tol_mm, self.block_bytes = max(int(chunk_rows), 1), chord_tol_mm, block_bytes
        self.progress = progress
        self.summary: ChunkSummary | None = None
        self.fraction = 0.0                          # of the bytes interpreted when the last chunk was handed over
        self.toolpath: Toolpath | None = None        # (no whole toolpath: see the chunks)
        self.path: str | os.PathLike[str] | None = None
        self.data: bytes | bytearray | None = None
        if isinstance(source, os.PathLike):
            self.path = source
            try:
                self.size = os.path.getsize(source)
                with open(source, "rb") as f:
                    self.head = f.read(HEAD_BYTES)
                    f.seek(max(self.size - HEAD_BYTES, len(self.head)))
                    self.tail = f.read(HEAD_BYTES)
            except FileNotFoundError as exc:
                raise NotFound(f"G-code file not found: {source}", file=str(source)) from exc
        else:
            if isinstance(source, str):
                self.data = source.encode("utf-8", "surrogateescape")
            else:
                self.data = source if isinstance(source, (bytes, bytearray)) else bytes(source)
            self.size = len(self.data)
            view = memoryview(self.data).cast("B")
            self.head = bytes(view[:HEAD_BYTES])
            self.tail = bytes(view[max(self.size - HEAD_BYTES, HEAD_BYTES):])
        self.slicer = detect_slicer(self.head[:8192])
        self.multiaxis = is_multiaxis(self.head)

    def material(self, n_lines: int = 0) -> Material:
        """What the file's comments state (``n_lines``, the file's line count, names the lines of errors in its
        tail; it is known once the chunks are through: :attr:`summary`)."""
        return read_material(self.head, self.tail, n_lines)

    def __iter__(self) -> Iterator[tuple[Toolpath, bool]]:
        interp = Interpreter(self.chord_tol_mm, rows_hint=self.chunk_rows + 2 * (self.block_bytes // 12),
                             multiaxis=self.multiaxis)
        done = 0
        with contextlib.ExitStack() as stack:
            if self.data is not None:
                view = memoryview(self.data).cast("B")
                blocks: Iterator[bytes | memoryview] = _memory_blocks(self.data, view, self.block_bytes)
            else:
                assert self.path is not None
                stream = stack.enter_context(open(self.path, "rb"))
                blocks = iter_blocks(stream, self.block_bytes)
            for lexed in lexed_blocks(blocks):
                interp.feed_lexed(lexed)
                done += len(lexed.block)
                if self.progress is not None:
                    self.progress(done / max(self.size, 1))
                while (tp := interp.take_chunk(self.chunk_rows)) is not None:
                    # a safe cut leaves at least the row after it: a cut chunk is never the last, so it goes
                    # to the planner at once (it used to wait for the next cut, a whole chunk's parse)
                    self.fraction = done / max(self.size, 1)
                    yield tp, False
        final = interp.take_chunk(0, final=True)
        assert final is not None                    # the final chunk is every row left
        self.summary = interp.chunk_summary()
        self.fraction = 1.0
        yield final, True
