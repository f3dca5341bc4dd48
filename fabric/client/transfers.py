"""Moving big files through the fabric: uploads in pieces, exports streamed to a file in chunks.

Both keep memory flat: an upload reads and sends one piece at a time (its size
checked before a byte is read); an export is fetched chunk by chunk while a
helper thread writes the previous chunk to disk.
"""
from __future__ import annotations

import hashlib
import os
import queue
import threading
import uuid
from collections.abc import Callable
from typing import BinaryIO

from fabric import schemas as s
from fabric.client.protocols import Caller
from fabric.schemas.upload import MIB, UPLOAD_CHUNK_BYTES, UPLOAD_CHUNK_MAX_BYTES
from fabric.wire.errors import BadRequest, ValidationError

__all__ = ["input_size", "upload_file", "export_to_file", "EXPORT_CHUNK_BYTES"]

# An export is fetched in chunks of this size: the planner's pieces. 145 MB of bare replies through a
# hub took a quarter of the CPU in 4 MB replies that it took in 16 MB ones on this machine class (Zenoh
# fragments, reassembles and re-fragments each reply at the hub); a whole `plan --csv` is bound by
# formatting, not by this, and took the same time with either.
EXPORT_CHUNK_BYTES = 4 << 20


def input_size(path: str | os.PathLike[str], max_bytes: int, limit_hint: str = "") -> int:
    """The size of an input file the user named, checked before it is read: BadRequest when it is not
    there, ValidationError (field ``size``) when it is larger than ``max_bytes`` (its message ends with
    ``limit_hint``, e.g. how the caller's user sets the limit)."""
    try:
        size = os.stat(path).st_size
    except OSError:
        raise BadRequest(f"no such file: {path}", file=str(path)) from None
    if not os.path.isfile(path):
        raise BadRequest(f"not a file: {path}", file=str(path))
    if size > max_bytes:
        raise ValidationError(f"{path} is {size / MIB:,.1f} MiB, more than the limit of {max_bytes / MIB:,.0f} MiB"
                              + (f" ({limit_hint})" if limit_hint else ""), field="size", file=str(path), value=size,
                              limit=max_bytes)
    return size


def upload_file(client: Caller, service: str, path: str | os.PathLike[str], max_bytes: int,
                chunk_bytes: int = UPLOAD_CHUNK_BYTES, on_progress: Callable[[int, int], None] | None = None) -> str:
    """Send a file to ``<service>/upload`` in pieces of ``chunk_bytes`` (its size checked against
    ``max_bytes`` before a byte is read, see :func:`input_size`); returns the upload id to name in the
    request (``PlanRequest.upload_id``, ``SliceRequest.upload_id``, ``JobSubmit.upload_id``). Memory: one piece."""
    size = input_size(path, max_bytes)
    uid = uuid.uuid4().hex
    digest = hashlib.sha256()
    offset = 0
    with open(path, "rb") as f:
        while True:
            data = f.read(min(chunk_bytes, UPLOAD_CHUNK_MAX_BYTES))
            digest.update(data)
            last = offset + len(data) >= size or not data
            client.call(service, "upload", s.UploadChunk(upload_id=uid, offset=offset, total_bytes=size, data=data,
                                                         sha256=digest.hexdigest() if last else ""))
            offset += len(data)
            if on_progress is not None:
                on_progress(offset, size)
            if last:
                return uid


def export_to_file(client: Caller, program_id: str, fmt: str, out: BinaryIO, module_targets: int = 5000,
                   limit_bytes: int = EXPORT_CHUNK_BYTES, *, job_id: str = "") -> int:
    """Stream an export into ``out`` chunk by chunk; returns the bytes written.

    A chunk is what the planner has formatted by the time it is asked, up to ``limit_bytes``. Chunks
    are written to ``out`` by a helper thread while the next one is fetched (memory: a few chunks).
    With ``job_id`` (``program_id`` empty) the export of a plan job still running starts as soon as its
    program is final (an empty chunk meanwhile: asked again)."""
    offset = 0
    with _ChunkWriter(out) as writer:
        while True:
            chunk = client.call("planner", "export_chunk", s.ExportChunkRequest(
                program_id=program_id, fmt=fmt, offset=offset, limit_bytes=limit_bytes, module_targets=module_targets,
                job_id=job_id))
            writer.write(chunk.data)
            offset += len(chunk.data)
            if chunk.done:
                return offset


class _ChunkWriter:
    """Writes chunks to a binary stream on a helper thread, at most ``depth`` chunks behind the fetching.

    Writing a large export to disk costs about as much as formatting it (page-cache pages are fresh
    memory), so the two overlap. A write error is raised by the next :meth:`write` or on exit.
    """

    def __init__(self, out: BinaryIO, depth: int = 2) -> None:
        self._out = out
        self._queue: queue.Queue[bytes | None] = queue.Queue(maxsize=depth)
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="export-file-writer", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            data = self._queue.get()
            if data is None:
                return
            if self._error is None:
                try:
                    self._out.write(data)
                except BaseException as exc:    # noqa: BLE001 - handed to the fetching thread
                    self._error = exc

    def write(self, data: bytes) -> None:
        if self._error is not None:
            raise self._error
        self._queue.put(data)

    def __enter__(self) -> _ChunkWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *_: object) -> None:
        self._queue.put(None)
        self._thread.join()
        if exc_type is None and self._error is not None:
            raise self._error
