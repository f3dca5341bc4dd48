"""The supervisor's durable state: print job records, the queue order, and how far it followed the station.

Job records are the typed :class:`~fabric.schemas.JobRecord` messages, stored
encoded with the fabric's codec, one row per job, with a ``position`` that
orders the queue (reordering rewrites positions, never records). The
database is opened with ``synchronous=FULL``: a job acknowledged to a client
has reached the disk. ``last_event_seq`` is the sequence number of the last
station event applied to the records, written in the same transaction as the
records it changed, so a restarted supervisor resumes following the station
exactly where it stopped.
"""
from __future__ import annotations

import threading
from pathlib import Path

from fabric.wire import codec
from fabric import schemas as s
from fabric.wire.errors import NotFound, ValidationError
from fabric.store.sqlite import open_db

__all__ = ["JobStore"]

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    job_id TEXT PRIMARY KEY,
    position REAL NOT NULL,
    record BLOB NOT NULL
);
CREATE TABLE IF NOT EXISTS follow (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    last_event_seq INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS plate (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    clear INTEGER NOT NULL
);
"""


class JobStore:
    """Job records in SQLite (see the module docstring). Thread-safe."""

    def __init__(self, path: str | Path) -> None:
        self._lock = threading.Lock()
        self._db = open_db(path, _SCHEMA, synchronous="FULL")

    # Records --------------------------------------------------------------------------------

    def add(self, record: s.JobRecord) -> None:
        """A new job at the end of the queue."""
        with self._lock, self._db:
            row = self._db.execute("SELECT COALESCE(MAX(position), 0) FROM jobs").fetchone()
            self._db.execute("INSERT INTO jobs VALUES (?, ?, ?)",
                             (record.job_id, float(row[0]) + 1.0, codec.encode(record)))

    def save(self, *records: s.JobRecord, last_event_seq: int | None = None) -> None:
        """Write changed records (and, with them, how far the station's events were applied)."""
        with self._lock, self._db:
            for rec in records:
                cur = self._db.execute("UPDATE jobs SET record = ? WHERE job_id = ?", (codec.encode(rec), rec.job_id))
                if cur.rowcount == 0:
                    raise NotFound(f"no job {rec.job_id}", job_id=rec.job_id)
            if last_event_seq is not None:
                self._db.execute("INSERT OR REPLACE INTO follow VALUES (1, ?)", (int(last_event_seq),))

    def get(self, job_id: str) -> s.JobRecord:
        """The record of ``job_id`` (NotFound when unknown)."""
        row = self._db.execute("SELECT record FROM jobs WHERE job_id = ?", (job_id,)).fetchone()
        if row is None:
            raise NotFound(f"no job {job_id}", job_id=job_id)
        return codec.decode(row[0], s.JobRecord)

    def all(self) -> list[s.JobRecord]:
        """Every record, in queue order (which is submission order unless reordered)."""
        rows = self._db.execute("SELECT record FROM jobs ORDER BY position").fetchall()
        return [codec.decode(r[0], s.JobRecord) for r in rows]

    def remove(self, job_id: str) -> None:
        """Forget ``job_id``."""
        with self._lock, self._db:
            if self._db.execute("DELETE FROM jobs WHERE job_id = ?", (job_id,)).rowcount == 0:
                raise NotFound(f"no job {job_id}", job_id=job_id)

    def move(self, job_id: str, index: int, among: list[str]) -> None:
        """Put ``job_id`` at ``index`` (0 = first) of the ordered ids ``among`` (the waiting queue)."""
        if job_id not in among:
            raise ValidationError(f"job {job_id} is not waiting in the queue", field="job_id", job_id=job_id)
        if not 0 <= index < len(among):
            raise ValidationError(f"position {index} outside the queue of {len(among)} jobs", field="position")
        order = [j for j in among if j != job_id]
        order.insert(index, job_id)
        with self._lock, self._db:
            slots = sorted(float(r[0]) for r in self._db.execute(
                f"SELECT position FROM jobs WHERE job_id IN ({','.join('?' * len(among))})", among))
            for pos, jid in zip(slots, order):
                self._db.execute("UPDATE jobs SET position = ? WHERE job_id = ?", (pos, jid))

    # Following the station, and the plate --------------------------------------------------------

    def last_event_seq(self) -> int:
        """The station event last applied (0 when none)."""
        row = self._db.execute("SELECT last_event_seq FROM follow WHERE id = 1").fetchone()
        return 0 if row is None else int(row[0])

    def plate_clear(self) -> bool:
        """Whether the operator confirmed the plate is clear since the last print began (initially yes)."""
        row = self._db.execute("SELECT clear FROM plate WHERE id = 1").fetchone()
        return True if row is None else bool(row[0])

    def set_plate_clear(self, clear: bool) -> None:
        with self._lock, self._db:
            self._db.execute("INSERT OR REPLACE INTO plate VALUES (1, ?)", (int(clear),))

    def close(self) -> None:
        with self._lock:
            self._db.close()
