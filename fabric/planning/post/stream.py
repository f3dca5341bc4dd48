"""An export as a stream of bounded chunks: a writer thread fills a short queue, readers take it in order.

A post-processor writes to a text stream. :class:`ExportStream` runs it on
its own thread into a :class:`_ChunkSink` that hands over ``piece_bytes``
pieces through a queue of ``depth`` pieces, so the writer formats the next
piece while the last one travels and is written to disk by the caller, and
no process ever holds more than a few pieces of the export. Readers ask by
byte offset: the next chunk must start where the previous one ended (a
stream is read once, in order); anything else is a :class:`BadRequest`.
"""
from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from typing import TextIO

from fabric.wire.errors import BadRequest, FabricError, InternalError, ServiceUnavailable

__all__ = ["ExportStream", "PIECE_BYTES"]

PIECE_BYTES = 4 << 20       # what the writer hands over at a time
QUEUE_DEPTH = 8             # pieces formatted ahead of the reader (32 MB: the writer never waits on a chunk in transit)
STALL_S = 120.0             # a writer whose reader went away gives up after this long


class _Cancelled(Exception):
    """The reader went away: the writer thread ends."""


class _Done:
    """End of the export (``error`` set if the writer failed)."""

    def __init__(self, error: FabricError | None = None) -> None:
        self.error = error


class _ChunkSink:
    """A write-only text stream that hands Latin-1 pieces of ``piece_bytes`` to a queue.

    Post-processors write ``str`` with :meth:`write`, and text they formatted
    as bytes with :meth:`write_bytes` (no decoding and encoding back).
    """

    def __init__(self, out: queue.Queue[bytes | _Done], piece_bytes: int, cancelled: threading.Event) -> None:
        self._out = out
        self._piece_bytes = piece_bytes
        self._cancelled = cancelled
        self._parts: list[bytes] = []
        self._size = 0

    def write(self, text: str) -> int:
        self.write_bytes(text.encode("latin-1"))
        return len(text)

    def write_bytes(self, data: bytes) -> None:
        self._parts.append(data)
        self._size += len(data)
        if self._size >= self._piece_bytes:
            self.flush()

    def flush(self) -> None:
        if not self._parts:
            return
        piece = self._parts[0] if len(self._parts) == 1 else b"".join(self._parts)
        self._parts = []
        self._size = 0
        self.put(piece)

    def put(self, item: bytes | _Done) -> None:
        while True:
            if self._cancelled.is_set():
                raise _Cancelled()
            try:
                self._out.put(item, timeout=STALL_S)
                return
            except queue.Full:
                self._cancelled.set()      # nobody read for STALL_S: give up


class ExportStream:
    """One export being written by ``write(text_stream)`` on a thread, read once in chunks from offset 0."""

    def __init__(self, write: Callable[[TextIO], None], name: str = "", piece_bytes: int = PIECE_BYTES,
                 depth: int = QUEUE_DEPTH) -> None:
        self.name = name
        self.offset = 0
        self.done = False
        self._queue: queue.Queue[bytes | _Done] = queue.Queue(maxsize=depth)
        self._pending = memoryview(b"")    # the rest of the piece being read (a view: no copy of the tail)
        self._cancelled = threading.Event()
        self._sink = _ChunkSink(self._queue, piece_bytes, self._cancelled)
        self._thread = threading.Thread(target=self._run, args=(write,), name="export-writer", daemon=True)
        self._thread.start()

    def _run(self, write: Callable[[TextIO], None]) -> None:
        try:
            try:
                write(self._sink)  # type: ignore[arg-type]  # write() is all a post-processor uses
                self._sink.flush()
                end = _Done()
            except FabricError as err:
                end = _Done(err)
            except _Cancelled:
                return
            except Exception as exc:  # noqa: BLE001 - a bug in a writer: the reader gets an internal error
                end = _Done(InternalError(f"export writer failed: {type(exc).__name__}: {exc}"))
            self._sink.put(end)
        except _Cancelled:
            return

    def read(self, offset: int, limit_bytes: int, timeout_s: float = 60.0, empty_on_timeout: bool = False) -> bytes:
        """:meth:`read_pieces` joined."""
        return b"".join(self.read_pieces(offset, limit_bytes, timeout_s, empty_on_timeout))

    def read_pieces(self, offset: int, limit_bytes: int, timeout_s: float = 60.0,
                    empty_on_timeout: bool = False) -> list[memoryview | bytes]:
        """The next at most ``limit_bytes`` bytes from ``offset`` (which must be where the last read ended),
        as views of the formatted pieces (joined once, where the reply is encoded).

        Waits for the first piece only (up to ``timeout_s``: then an error, or with ``empty_on_timeout``
        no bytes, the stream not done: a writer still waiting for its input); the pieces already
        formatted after it are added up to the limit. ``self.done`` is set once the last bytes have been
        returned.
        """
        if offset != self.offset:
            raise BadRequest(f"export chunks are read in order: offset {offset}, the stream stands at {self.offset}",
                             field="offset", value=offset, expected=self.offset)
        if self.done:
            return []
        while not self._pending:
            try:
                item = self._queue.get(timeout=timeout_s)
            except queue.Empty:
                if empty_on_timeout:
                    return []
                raise ServiceUnavailable(f"export writer produced nothing within {timeout_s:g} s",
                                         timeout_s=timeout_s) from None
            if isinstance(item, _Done):
                if item.error is not None:
                    self.cancel()
                    raise item.error
                self.done = True
                return []
            self._pending = memoryview(item)
        parts: list[memoryview | bytes] = [self._take(limit_bytes)]
        size = len(parts[0])
        while True:
            if not self._pending:
                self._peek_end()            # the next piece if it is ready already (or the end)
            if not self._pending or size >= limit_bytes:
                break
            parts.append(self._take(limit_bytes - size))
            size += len(parts[-1])
        self.offset += size
        return parts

    def _take(self, limit_bytes: int) -> memoryview:
        part = self._pending[:limit_bytes]
        self._pending = self._pending[limit_bytes:]
        return part

    def _peek_end(self) -> None:
        # mark the stream done with its last bytes when the writer has already finished
        try:
            item = self._queue.get_nowait()
        except queue.Empty:
            return
        if isinstance(item, _Done) and item.error is None:
            self.done = True
        elif isinstance(item, _Done):
            self._queue.put(item)          # the error is raised by the next read
        else:
            self._pending = memoryview(item)

    def cancel(self) -> None:
        """Stop the writer (it ends at its next piece) and drop what it queued."""
        self._cancelled.set()
        while True:
            try:
                self._queue.get_nowait()
            except queue.Empty:
                return
