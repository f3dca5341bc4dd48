"""Content-addressed artifacts on disk: atomic writes, hashes verified on read, bounded size, pins.

An artifact (G-code, a program, a model) is stored as one file named by the
sha256 of its data, ``<root>/<id[:2]>/<id>``, holding the encoded
:class:`~fabric.schemas.Artifact` (name, media type, data). A write goes to a
temporary file in the same directory, is flushed and fsynced, then renamed
over the final name (and the directory fsynced), so a crash leaves either the
whole artifact or nothing. A read checks the data's hash against the id: a
file damaged on disk is removed and reported, never served.

The store is bounded (``max_bytes``): when a write takes it over, the least
recently used artifacts are evicted first, except *pinned* ones. A pin names
an owner (a job id): the supervisor pins what a queued or active job needs and
unpins it when the job ends, so eviction never removes those. Pins and the
use order live in a small SQLite index beside the files, so they survive
restarts too.
"""
from __future__ import annotations

import logging
import os
import tempfile
import threading
import time
from pathlib import Path

from fabric.programs import content_id
from fabric.schemas import Artifact
from fabric.store.sqlite import open_db
from fabric.wire import codec
from fabric.wire.errors import DecodeError, NotFound, ValidationError

__all__ = ["ArtifactStore", "DEFAULT_MAX_BYTES", "INDEX_SCHEMA"]

log = logging.getLogger("fabric.store.artifacts")
DEFAULT_MAX_BYTES = 4 << 30

INDEX_SCHEMA = """
CREATE TABLE IF NOT EXISTS artifacts (
    artifact_id TEXT PRIMARY KEY,
    size_bytes INTEGER NOT NULL,
    used_s REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS pins (
    artifact_id TEXT NOT NULL,
    owner TEXT NOT NULL,
    PRIMARY KEY (artifact_id, owner)
);
"""


def _check_id(artifact_id: str) -> None:
    if len(artifact_id) != 64 or any(c not in "0123456789abcdef" for c in artifact_id):
        raise ValidationError(f"artifact id {artifact_id!r} is not a sha256 hex digest", field="artifact_id")


class ArtifactStore:
    """Artifacts of one service under ``root`` (see module docstring); safe to share between threads."""

    def __init__(self, root: str | Path, max_bytes: int = DEFAULT_MAX_BYTES) -> None:
        if max_bytes <= 0:
            raise ValidationError(f"max_bytes must be > 0, got {max_bytes}", field="max_bytes")
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.max_bytes = int(max_bytes)
        self._lock = threading.Lock()
        self._db = open_db(self.root / "index.sqlite", INDEX_SCHEMA, synchronous="FULL")
        self._reconcile()

    # Reading and writing ------------------------------------------------------------------

    def put(self, artifact: Artifact) -> str:
        """Store ``artifact`` (its id must be the sha256 of its data); returns the id."""
        _check_id(artifact.artifact_id)
        if content_id(artifact.data) != artifact.artifact_id:
            raise ValidationError("artifact id is not the sha256 of its data", field="artifact_id",
                                  artifact_id=artifact.artifact_id)
        return self.put_encoded(artifact.artifact_id, codec.encode_pieces(artifact))

    def put_encoded(self, artifact_id: str, pieces: list[codec.Buffer]) -> str:
        """Store an artifact given as the pieces of its encoded message (``codec.encode_pieces`` of an
        Artifact whose id its maker computed from the very data, e.g. ``program_artifact_pieces``): a
        large artifact is written from the caller's memory, never joined or hashed again here (its
        hash is checked whenever it is read)."""
        _check_id(artifact_id)
        path = self._path(artifact_id)
        with self._lock:
            if not path.exists():
                _write_atomic(path, pieces)
            size = path.stat().st_size
            with self._db:
                self._db.execute("INSERT OR REPLACE INTO artifacts VALUES (?, ?, ?)",
                                 (artifact_id, size, time.time()))
            self._evict()
        return artifact_id

    def get(self, artifact_id: str) -> Artifact:
        """The artifact ``artifact_id`` (NotFound if absent or damaged on disk)."""
        _check_id(artifact_id)
        path = self._path(artifact_id)
        with self._lock:
            try:
                data = path.read_bytes()
            except FileNotFoundError:
                raise NotFound(f"no artifact {artifact_id}", artifact_id=artifact_id) from None
            try:
                art = codec.decode(data, Artifact)
                good = art.artifact_id == artifact_id and content_id(art.data) == artifact_id
            except (DecodeError, ValidationError) as exc:      # the file is damaged
                log.error("artifact %s does not decode (%s): removing it", artifact_id, exc)
                good = False
            if not good:
                log.error("artifact %s is damaged on disk (hash mismatch): removing it", artifact_id)
                self._remove(artifact_id)
                raise NotFound(f"artifact {artifact_id} was damaged on disk and has been removed",
                               artifact_id=artifact_id)
            with self._db:
                self._db.execute("UPDATE artifacts SET used_s = ? WHERE artifact_id = ?", (time.time(), artifact_id))
        return art

    def has(self, artifact_id: str) -> bool:
        """Whether the artifact is stored (without reading it)."""
        _check_id(artifact_id)
        return self._path(artifact_id).exists()

    def total_bytes(self) -> int:
        """Bytes used by the stored artifacts."""
        row = self._db.execute("SELECT COALESCE(SUM(size_bytes), 0) FROM artifacts").fetchone()
        return int(row[0])

    def ids(self) -> list[str]:
        """Stored artifact ids, least recently used first."""
        return [r[0] for r in self._db.execute("SELECT artifact_id FROM artifacts ORDER BY used_s")]

    # Pins ------------------------------------------------------------------------------------

    def pin(self, artifact_id: str, owner: str) -> None:
        """Keep ``artifact_id`` from eviction while ``owner`` (a job id) needs it."""
        _check_id(artifact_id)
        with self._lock, self._db:
            self._db.execute("INSERT OR IGNORE INTO pins VALUES (?, ?)", (artifact_id, owner))

    def unpin(self, owner: str) -> None:
        """Release every pin of ``owner``; evicts if the store is over its size."""
        with self._lock:
            with self._db:
                self._db.execute("DELETE FROM pins WHERE owner = ?", (owner,))
            self._evict()

    def pinned(self) -> set[str]:
        """Ids pinned by any owner."""
        return {r[0] for r in self._db.execute("SELECT DISTINCT artifact_id FROM pins")}

    def close(self) -> None:
        """Close the index (the files stay)."""
        with self._lock:
            self._db.close()

    # Internals ------------------------------------------------------------------------------------

    def _path(self, artifact_id: str) -> Path:
        return self.root / artifact_id[:2] / artifact_id

    def _evict(self) -> None:
        """Remove least recently used, unpinned artifacts until the store fits (lock held)."""
        total = self.total_bytes()
        if total <= self.max_bytes:
            return
        rows = self._db.execute(
            "SELECT artifact_id, size_bytes FROM artifacts "
            "WHERE artifact_id NOT IN (SELECT artifact_id FROM pins) ORDER BY used_s").fetchall()
        for artifact_id, size in rows:
            if total <= self.max_bytes:
                break
            self._remove(artifact_id)
            total -= size
            log.info("evicted artifact %s (%d bytes) to stay under %d bytes", artifact_id, size, self.max_bytes)

    def _remove(self, artifact_id: str) -> None:
        try:
            self._path(artifact_id).unlink()
        except FileNotFoundError:
            pass                                   # already gone: only the index row is left to drop
        with self._db:
            self._db.execute("DELETE FROM artifacts WHERE artifact_id = ?", (artifact_id,))

    def _reconcile(self) -> None:
        """Bring the index in line with the files (a crash between a rename and the index write, or
        files removed by hand): index every artifact file, drop rows without one, remove stray temp files."""
        on_disk: dict[str, int] = {}
        for sub in self.root.iterdir():
            if not sub.is_dir() or len(sub.name) != 2:
                continue
            for f in sub.iterdir():
                if f.name.startswith(".tmp-"):
                    f.unlink(missing_ok=True)
                elif len(f.name) == 64:
                    on_disk[f.name] = f.stat().st_size
        known = {r[0] for r in self._db.execute("SELECT artifact_id FROM artifacts")}
        now = time.time()
        with self._db:
            for artifact_id in known - set(on_disk):
                self._db.execute("DELETE FROM artifacts WHERE artifact_id = ?", (artifact_id,))
            for artifact_id in set(on_disk) - known:
                self._db.execute("INSERT INTO artifacts VALUES (?, ?, ?)", (artifact_id, on_disk[artifact_id], now))


def _write_atomic(path: Path, pieces: list[codec.Buffer]) -> None:
    """Write ``pieces`` to ``path`` all-or-nothing: temp file, fsync, rename, fsync the directory."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            for piece in pieces:
                fh.write(piece)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)
