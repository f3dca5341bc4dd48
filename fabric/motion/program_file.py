"""Programs built in row blocks: in memory, or in files whose pages the process gives back as it reads on.

A planner writes a program chunk by chunk (:mod:`fabric.planning.planner`) into a
*sink*:

* :class:`MemorySink` keeps growing columns in memory (capacity from a size hint,
  trimmed in place at the end: no final copy) and makes an ordinary
  :class:`~fabric.motion.program.Program`;
* :class:`FileSink` appends every column to a file of its own in a directory (raw
  little-endian, C order; written by a thread of its own, a block behind the caller, so the
  planner goes on with the next chunk meanwhile) and maps the files read-only at the end: a program of
  17 M rows (2.9 GB of columns) then lives in files and the page cache, not in the
  process. Its :class:`ColumnPager` is the program's ``pager``: code that walks
  such a program in blocks calls :meth:`Program.release_pages` for the rows it is
  done with, and the mapped pages leave the process's resident memory (the data
  stays in the page cache; touching it again maps it back). Without that a
  walk over a mapped program would keep every page it touched resident.

Extra per-row columns made alongside (the reachability status, the rows' times)
go to the same directory (:meth:`FileSink.column`) and are released with the
program's rows.
"""
from __future__ import annotations

import mmap
import os
import queue
import shutil
import threading
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fabric.gcode.toolpath import RowColumns
from fabric.motion.program import COLUMNS, DEFAULT_NQ, Program, column_spec

__all__ = ["MemorySink", "FileSink", "ColumnPager", "ProgramSink", "column_pieces", "PIECE_BYTES"]

PIECE_BYTES = 8 << 20           # a column read back from its file this much at a time (artifact, hash)
_PAGE = mmap.PAGESIZE


class ColumnPager:
    """Mapped column files of one program: gives back the resident pages of row ranges."""

    def __init__(self) -> None:
        self._maps: list[tuple[mmap.mmap, int]] = []      # (mapping, bytes per row)
        self.files: dict[str, Path] = {}

    def add(self, path: Path, dtype: np.dtype, shape: tuple[int, ...], n: int, writable: bool = False) -> np.ndarray:
        """Map ``path`` as an (n, *shape) array of ``dtype`` (created, zero-filled, when ``writable``)."""
        row_bytes = int(dtype.itemsize * int(np.prod(shape, dtype=np.int64)))
        size = n * row_bytes
        if writable:
            with open(path, "wb") as f:
                f.truncate(size)
        self.files[path.stem] = path
        if size == 0:
            return np.zeros((0, *shape), dtype)
        with open(path, "r+b" if writable else "rb") as f:
            mm = mmap.mmap(f.fileno(), size, access=mmap.ACCESS_WRITE if writable else mmap.ACCESS_READ)
        self._maps.append((mm, row_bytes))
        arr = np.frombuffer(mm, dtype=dtype, count=n * int(np.prod(shape, dtype=np.int64))).reshape(n, *shape)
        if writable:
            return arr
        arr.flags.writeable = False
        return arr

    def release(self, start: int = 0, stop: int | None = None) -> None:
        """Give back the resident pages of rows ``[start, stop)`` of every mapped column (whole pages inside
        the range; the rows can be read again, from the page cache)."""
        for mm, row_bytes in self._maps:
            a = max(start, 0) * row_bytes
            _release(mm, a, len(mm) if stop is None else stop * row_bytes)


def _release(mm: mmap.mmap, a: int, b: int) -> None:
    """``madvise(MADV_DONTNEED)`` on the whole pages of bytes ``[a, b)`` of a mapping (its end counts whole)."""
    if not hasattr(mmap, "MADV_DONTNEED"):
        return
    try:
        size = len(mm)
    except ValueError:                                  # closed meanwhile (the program was dropped)
        return
    b = min(b, size)
    a = -(-a // _PAGE) * _PAGE
    b = b if b == size else b // _PAGE * _PAGE
    if b > a:
        try:
            mm.madvise(mmap.MADV_DONTNEED, a, b - a)
        except (ValueError, OSError):
            pass


def _mapping(arr: np.ndarray) -> tuple[mmap.mmap, int] | None:
    """The file mapping behind ``arr`` (one of :class:`ColumnPager`'s) and where ``arr``'s data starts in it."""
    base: Any = arr
    prev: np.ndarray | None = None
    while isinstance(base, np.ndarray):
        prev, base = base, base.base
    if isinstance(base, memoryview):            # np.frombuffer(mapping) keeps a view of the mapping
        base = base.obj
    if isinstance(base, mmap.mmap) and prev is not None:
        return base, int(arr.__array_interface__["data"][0]) - int(prev.__array_interface__["data"][0])
    return None


class MemorySink:
    """Program rows appended in blocks to columns in memory."""

    def __init__(self, rows_hint: int = 0, extra: Mapping[str, tuple[str, tuple[int, ...]]] | None = None,
                 nq: int = DEFAULT_NQ) -> None:
        self.spec = {**column_spec(nq), **(extra or {})}
        self._cols = RowColumns(self.spec, rows_hint)

    @property
    def n(self) -> int:
        return self._cols.n

    def append(self, cols: dict[str, np.ndarray]) -> None:
        self._cols.append(cols)

    def finish(self, wobj: np.ndarray, meta: dict[str, Any]) -> tuple[Program, dict[str, np.ndarray]]:
        """The program and the extra columns."""
        cols = self._cols.take()
        prog = Program(**{k: cols[k] for k in COLUMNS}, wobj=wobj, meta=meta)
        return prog, {k: v for k, v in cols.items() if k not in COLUMNS}

    def column(self, name: str, dtype: str, n: int) -> np.ndarray:
        """A new per-row column (e.g. the rows' times), in memory."""
        return np.empty(n, dtype)


class FileSink:
    """Program rows appended in blocks to one file per column in ``directory`` (created; see the module doc).

    The blocks are written by a writer thread, at most ``depth`` blocks behind :meth:`append` (a block's
    arrays must not change once appended); a write's error (a full disk) is raised by the next
    :meth:`append` and by :meth:`finish`: the files lack blocks from then on, so the sink can only be
    discarded.
    """

    def __init__(self, directory: str | os.PathLike[str],
                 extra: Mapping[str, tuple[str, tuple[int, ...]]] | None = None, nq: int = DEFAULT_NQ,
                 depth: int = 1) -> None:
        self.dir = Path(directory)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.spec = {**column_spec(nq), **(extra or {})}
        self._files = {k: open(self.dir / f"{k}.col", "wb") for k in self.spec}  # noqa: SIM115  (closed in finish)
        self._n = 0
        self.pager = ColumnPager()
        self._blocks: queue.Queue[dict[str, np.ndarray] | None] = queue.Queue(maxsize=depth)
        self._error: BaseException | None = None
        self._writer: threading.Thread | None = None

    @property
    def n(self) -> int:
        return self._n

    def append(self, cols: dict[str, np.ndarray]) -> None:
        m = len(next(iter(cols.values())))
        for k, (_dtype, shape) in self.spec.items():
            if cols[k].shape != (m, *shape):
                raise ValueError(f"column {k}: shape {cols[k].shape}, expected {(m, *shape)}")
        self._raise_error()
        if self._writer is None:
            self._writer = threading.Thread(target=self._write_blocks, name="program-file-writer", daemon=True)
            self._writer.start()
        self._blocks.put({k: cols[k] for k in self.spec})
        self._n += m

    def _write_blocks(self) -> None:
        while True:
            cols = self._blocks.get()
            if cols is None:
                return
            if self._error is not None:
                continue                        # drained, not written: the error is raised to the caller
            try:
                for k, (dtype, _shape) in self.spec.items():
                    arr = np.ascontiguousarray(cols[k], dtype=np.dtype(dtype).newbyteorder("<"))
                    self._files[k].write(arr.data.cast("B") if arr.size else b"")
            except BaseException as exc:        # noqa: BLE001 - raised by the caller's next append or finish
                self._error = exc

    def _stop_writer(self) -> None:
        """Wait for the blocks appended to be written (or dropped after an error); the writer ends."""
        if self._writer is not None:
            self._blocks.put(None)
            self._writer.join()
            self._writer = None

    def _raise_error(self) -> None:
        if self._error is not None:
            self._stop_writer()
            raise self._error

    def finish(self, wobj: np.ndarray, meta: dict[str, Any]) -> tuple[Program, dict[str, np.ndarray]]:
        """The program mapped from its files (read-only columns, ``pager`` set) and the extra columns."""
        self._stop_writer()
        self._raise_error()
        for f in self._files.values():
            f.close()
        cols = {k: self.pager.add(self.dir / f"{k}.col", np.dtype(dtype).newbyteorder("<"), shape, self._n)
                for k, (dtype, shape) in self.spec.items()}
        prog = Program(**{k: cols[k] for k in COLUMNS}, wobj=wobj, meta=meta, pager=self.pager)
        return prog, {k: v for k, v in cols.items() if k not in COLUMNS}

    def column(self, name: str, dtype: str, n: int) -> np.ndarray:
        """A new per-row column mapped from a file of its own (writable; its pages released with the rows')."""
        return self.pager.add(self.dir / f"{name}.col", np.dtype(dtype).newbyteorder("<"), (), n, writable=True)

    def discard(self) -> None:
        """Close the files and remove the directory (mapped columns stay readable until they are dropped)."""
        self._stop_writer()
        for f in self._files.values():
            try:
                f.close()
            except OSError:                     # its last buffered bytes did not fit: the files go anyway
                pass
        shutil.rmtree(self.dir, ignore_errors=True)


ProgramSink = MemorySink | FileSink


def column_pieces(arr: np.ndarray, piece_bytes: int = PIECE_BYTES) -> Iterator[memoryview]:
    """The bytes of a C-contiguous array in pieces of at most ``piece_bytes`` (views, no copies). When the
    array is mapped from a file, the pages of each piece are given back once the next one is asked for,
    so reading a mapped column through (to hash it, to write it) keeps one piece resident."""
    data = arr.data.cast("B") if arr.size else memoryview(b"")
    mapped = _mapping(arr)
    n = len(data)
    for a in range(0, n, piece_bytes):
        yield data[a:a + piece_bytes]
        if mapped is not None:
            mm, off = mapped
            _release(mm, off + a, off + min(a + piece_bytes, n))
