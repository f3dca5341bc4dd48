"""Chunked uploads assembled on disk: a service's side of ``<service>/upload`` (see fabric.schemas.upload).

Each upload is one file under the service's data folder, ``<id>.part`` while
pieces arrive in order, renamed ``<id>.input`` once the last piece came and the
whole file's sha256 matched. Only the piece in hand is in memory; the hash is
computed as the pieces arrive. A restart of the service loses the partial ones
(the client starts again at offset 0). At most ``max_open`` uploads are kept
open, and as many completed ones: the oldest beyond that is dropped (a client
that went away leaves no litter).
"""
from __future__ import annotations

import hashlib
import re
import threading
from dataclasses import dataclass, field
from pathlib import Path

from fabric.schemas.ids import UPLOAD_ID_PATTERN
from fabric.schemas.upload import MIB, UPLOAD_CHUNK_MAX_BYTES, UploadChunk, UploadStatus
from fabric.server.disk import require_room
from fabric.wire.errors import BadRequest, NotFound, ValidationError

__all__ = ["UploadStore"]

_ID = re.compile(UPLOAD_ID_PATTERN)
_CHUNK: str = UploadChunk.TYPE  # type: ignore[attr-defined]  # the message whose fields these checks are about


@dataclass
class _Partial:
    total_bytes: int
    received_bytes: int = 0
    digest: hashlib._Hash = field(default_factory=hashlib.sha256)


class UploadStore:
    """Uploads of one service: pieces in order -> a verified file on disk, used once and removed."""

    def __init__(self, root: Path, max_bytes: int, max_open: int = 4) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        for stale in self.root.glob("*.part"):          # pieces of a run before a restart: never completed
            stale.unlink(missing_ok=True)
        self.max_bytes, self.max_open = int(max_bytes), int(max_open)
        self._open: dict[str, _Partial] = {}
        self._lock = threading.Lock()

    def put(self, chunk: UploadChunk) -> UploadStatus:
        """Take the next piece of an upload; the last one (offset + len == total) checks the sha256."""
        uid = chunk.upload_id
        if not _ID.fullmatch(uid):
            raise ValidationError(f"upload_id must match {UPLOAD_ID_PATTERN}", field="upload_id", value=uid[:64],
                                  schema=_CHUNK)
        if chunk.total_bytes > self.max_bytes:
            raise ValidationError(f"the input is {chunk.total_bytes / MIB:.1f} MiB, more than this service takes "
                                  f"({self.max_bytes / MIB:.0f} MiB)", field="total_bytes",
                                  value=chunk.total_bytes, limit=self.max_bytes, schema=_CHUNK)
        if len(chunk.data) > UPLOAD_CHUNK_MAX_BYTES:
            raise ValidationError(f"a piece is at most {UPLOAD_CHUNK_MAX_BYTES / MIB:g} MiB", field="data",
                                  value=len(chunk.data), schema=_CHUNK)
        with self._lock:
            part = self._open.get(uid)
            if chunk.offset == 0:
                require_room(self.root, chunk.total_bytes, self.root.parent.name or "service", "this upload")
                part = self._start(uid, chunk.total_bytes)
            elif part is None or chunk.offset != part.received_bytes:
                expected = 0 if part is None else part.received_bytes
                raise BadRequest(f"upload {uid}: piece at offset {chunk.offset}, expected {expected} "
                                 "(start again at offset 0)", field="offset", value=chunk.offset, expected=expected)
            if chunk.total_bytes != part.total_bytes or part.received_bytes + len(chunk.data) > part.total_bytes:
                self._drop(uid)
                raise BadRequest(f"upload {uid}: pieces add up to more than total_bytes = {part.total_bytes}",
                                 field="total_bytes", value=chunk.total_bytes)
            with open(self._part(uid), "ab") as out:
                out.write(chunk.data)
            part.digest.update(chunk.data)
            part.received_bytes += len(chunk.data)
            if part.received_bytes < part.total_bytes:
                return UploadStatus(upload_id=uid, received_bytes=part.received_bytes, done=False)
            got = part.digest.hexdigest()
            if chunk.sha256 != got:
                self._drop(uid)
                raise BadRequest(f"upload {uid}: the sha256 of what arrived is {got[:12]}..., not "
                                 f"{chunk.sha256[:12] or '(none given)'}: send it again", field="sha256")
            self._part(uid).replace(self._done(uid))
            del self._open[uid]
            self._keep_newest_done()
            return UploadStatus(upload_id=uid, received_bytes=part.received_bytes, done=True)

    def path(self, upload_id: str) -> Path:
        """The file of a completed upload (NotFound when there is none)."""
        path = self._done(upload_id) if _ID.fullmatch(upload_id) else None
        if path is None or not path.is_file():
            raise NotFound(f"no completed upload {upload_id[:64]!r} (send it to <service>/upload first)",
                           upload_id=upload_id[:64])
        return path

    def discard(self, upload_id: str) -> None:
        """Remove a completed upload once used."""
        if _ID.fullmatch(upload_id):
            self._done(upload_id).unlink(missing_ok=True)

    # -- files ----------------------------------------------------------------

    def _start(self, uid: str, total_bytes: int) -> _Partial:
        self._drop(uid)
        while len(self._open) >= self.max_open:               # the oldest upload still open goes
            self._drop(next(iter(self._open)))
        self._part(uid).write_bytes(b"")
        part = self._open[uid] = _Partial(total_bytes)
        return part

    def _keep_newest_done(self) -> None:
        """Completed uploads nobody used: only the newest ``max_open`` stay."""
        done = sorted(self.root.glob("*.input"), key=lambda p: p.stat().st_mtime_ns)
        for old in done[:-self.max_open]:
            old.unlink(missing_ok=True)

    def _drop(self, uid: str) -> None:
        self._open.pop(uid, None)
        self._part(uid).unlink(missing_ok=True)

    def _part(self, uid: str) -> Path:
        return self.root / f"{uid}.part"

    def _done(self, uid: str) -> Path:
        return self.root / f"{uid}.input"
