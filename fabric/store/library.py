"""The supervisor's file library on disk: one row per entry (a file's content and its name).

An entry's ``file_id`` is derived from the content id and the name, so the same file submitted twice under
one name is one entry (its job count grows), and the same bytes under two names are two entries (people
name their files; a renamed copy is a different thing on a shelf). The bytes themselves are an artifact of
the supervisor's content-addressed store, pinned by the owner ``library`` while the entry exists. The entry
is kept as the typed :class:`~fabric.schemas.LibraryFile` beside the columns that are queried (name, last
use). Table ``library`` v1, in ``library.sqlite`` (its own file: the job store's tables are versioned apart).
"""
from __future__ import annotations

import hashlib
from pathlib import Path

from fabric import schemas as s
from fabric.schemas.ids import FILE_ID_MIN_CHARS
from fabric.store.sqlite import Database, Table
from fabric.wire import codec
from fabric.wire.errors import NotFound, ValidationError

__all__ = ["LIBRARY_TABLE", "LibraryStore", "entry_id", "MIN_ID_PREFIX"]

MIN_ID_PREFIX = FILE_ID_MIN_CHARS     # a shorter prefix of a file id is refused (too easy to mean two files)

LIBRARY_TABLE = Table("library", 1, """
CREATE TABLE library (
    file_id TEXT PRIMARY KEY,
    name TEXT NOT NULL,
    content_id TEXT NOT NULL,
    last_job_id TEXT NOT NULL,
    used_s REAL NOT NULL,
    entry BLOB NOT NULL
);
CREATE INDEX library_used ON library (used_s);
CREATE INDEX library_content ON library (content_id);
CREATE INDEX library_last_job ON library (last_job_id)
""")


def entry_id(content_id: str, name: str) -> str:
    """The library id of ``name`` holding the bytes ``content_id`` (12 hex digits, as job ids)."""
    return hashlib.sha256(f"{content_id}\0{name}".encode()).hexdigest()[:12]


class LibraryStore:
    """Library entries in SQLite. Thread-safe (every access holds the database's lock)."""

    def __init__(self, path: str | Path) -> None:
        self.db = Database(path, (LIBRARY_TABLE,), synchronous="FULL")

    def put(self, entry: s.LibraryFile) -> None:
        """Add or replace ``entry``."""
        with self.db.write() as conn:
            conn.execute("INSERT OR REPLACE INTO library VALUES (?, ?, ?, ?, ?, ?)",
                         (entry.file_id, entry.name, entry.content_id, entry.last_job_id,
                          max(entry.used_s, entry.added_s), codec.encode(entry)))

    def find(self, file_id: str) -> s.LibraryFile | None:
        """The entry ``file_id`` exactly (None when there is none)."""
        with self.db.read() as conn:
            row = conn.execute("SELECT entry FROM library WHERE file_id = ?", (file_id,)).fetchone()
        return None if row is None else _entry(row[0])

    def get(self, file_id: str) -> s.LibraryFile:
        """The entry ``file_id`` or the one entry whose id starts with it (at least ``MIN_ID_PREFIX``
        characters); NotFound / ValidationError say which it was not."""
        exact = self.find(file_id)
        if exact is not None:
            return exact
        if len(file_id) < MIN_ID_PREFIX:
            raise ValidationError(f"file id {file_id!r} is too short: give at least {MIN_ID_PREFIX} characters "
                                  f"(fabric-cli files list shows them)", field="file_id", value=file_id)
        with self.db.read() as conn:
            rows = conn.execute("SELECT entry FROM library WHERE file_id LIKE ? LIMIT 2",
                                (file_id.replace("%", "").replace("_", "") + "%",)).fetchall()
        if not rows:
            raise NotFound(f"no file {file_id} in the library", file_id=file_id)
        if len(rows) > 1:
            raise ValidationError(f"file id {file_id!r} names more than one library file: give more of it",
                                  field="file_id", value=file_id)
        return _entry(rows[0][0])

    def page(self, offset: int, limit: int, name_contains: str = "") -> tuple[list[s.LibraryFile], int]:
        """``limit`` entries from the ``offset``-th, most recently used first, and how many matched."""
        where, params = ("", ()) if not name_contains else (" WHERE instr(lower(name), ?) > 0",
                                                            (name_contains.lower(),))
        with self.db.read() as conn:
            total = int(conn.execute(f"SELECT COUNT(*) FROM library{where}", params).fetchone()[0])
            rows = conn.execute(f"SELECT entry FROM library{where} ORDER BY used_s DESC, name LIMIT ? OFFSET ?",
                                (*params, int(limit), int(offset))).fetchall()
        return [_entry(r[0]) for r in rows], total

    def by_job(self, job_id: str) -> s.LibraryFile | None:
        """The entry whose last job is ``job_id`` (None: none, or a later job was made from it since)."""
        if not job_id:
            return None
        with self.db.read() as conn:
            row = conn.execute("SELECT entry FROM library WHERE last_job_id = ?", (job_id,)).fetchone()
        return None if row is None else _entry(row[0])

    def holds_content(self, content_id: str) -> bool:
        """Whether any entry keeps the bytes ``content_id`` (another name may share them)."""
        with self.db.read() as conn:
            return conn.execute("SELECT 1 FROM library WHERE content_id = ?", (content_id,)).fetchone() is not None

    def remove(self, file_id: str) -> None:
        with self.db.write() as conn:
            if conn.execute("DELETE FROM library WHERE file_id = ?", (file_id,)).rowcount == 0:
                raise NotFound(f"no file {file_id} in the library", file_id=file_id)

    def close(self) -> None:
        self.db.close()


def _entry(blob: bytes) -> s.LibraryFile:
    """An entry as stored. Entries written before the library kept only estimates >= 0 may hold the planner's
    -1 ("cannot be timed") of a job whose targets were unreachable, which the schema refuses: read as 0 (no
    estimate), so the file can be printed again."""
    body = codec.unpack(blob)
    if isinstance(body, dict) and isinstance(body.get("estimate_s"), float | int) and body["estimate_s"] < 0:
        body["estimate_s"] = 0.0
        blob = codec.pack(body)
    return codec.decode(blob, s.LibraryFile)
