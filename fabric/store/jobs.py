"""The supervisor's durable state: print job records, the queue order, and how far it followed the station.

Job records are the typed :class:`~fabric.schemas.JobRecord` messages, stored
encoded with the fabric's codec, one row per job, beside columns for what is
queried (state, times, file name) so that listing a page, finding the jobs in
some states or the latest one never decodes the whole table. A ``position``
orders the queue (reordering rewrites positions, never records). The
database is opened with ``synchronous=FULL``: a job acknowledged to a client
has reached the disk. ``last_event_seq`` is the sequence number of the last
station event applied to the records, written in the same transaction as the
records it changed, so a restarted supervisor resumes following the station
exactly where it stopped.

Tables and versions (see :mod:`fabric.store.sqlite`): ``jobs`` v2 (v1, in
release 0.1.0, held only ``job_id``, ``position`` and the record), ``follow``
v1, ``plate`` v1.
"""
from __future__ import annotations

import sqlite3
from collections.abc import Iterable
from pathlib import Path

from fabric import schemas as s
from fabric.server.writer import Writer
from fabric.store.sqlite import Database, Table, run_script
from fabric.wire import codec
from fabric.wire.errors import NotFound, ValidationError

__all__ = ["FOLLOW_TABLE", "JOBS_TABLE", "PLATE_TABLE", "JobStore"]

_JOBS_V2 = """
CREATE TABLE jobs (
    job_id TEXT PRIMARY KEY,
    position REAL NOT NULL,
    state TEXT NOT NULL,
    filename TEXT NOT NULL,
    created_s REAL NOT NULL,
    updated_s REAL NOT NULL,
    started_s REAL NOT NULL,
    ended_s REAL NOT NULL,
    record BLOB NOT NULL
);
CREATE INDEX jobs_position ON jobs (position);
CREATE INDEX jobs_state_position ON jobs (state, position);
CREATE INDEX jobs_updated ON jobs (updated_s)
"""
_COLUMNS = "state = ?, filename = ?, created_s = ?, updated_s = ?, started_s = ?, ended_s = ?, record = ?"


def _columns(rec: s.JobRecord) -> tuple[str, str, float, float, float, float]:
    """What the queried columns hold for ``rec`` (the record itself goes beside them)."""
    return rec.state, rec.filename, rec.created_s, rec.updated_s, rec.started_s, rec.ended_s


def _jobs_1_to_2(conn: sqlite3.Connection) -> None:
    """Release 0.1.0's ``jobs`` (job_id, position, record) -> columns read from each record."""
    rows = conn.execute("SELECT job_id, position, record FROM jobs").fetchall()
    conn.execute("ALTER TABLE jobs RENAME TO jobs_v1")
    run_script(conn, _JOBS_V2)
    for job_id, position, blob in rows:
        rec = codec.decode(blob, s.JobRecord)
        conn.execute("INSERT INTO jobs VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                     (job_id, position, *_columns(rec), blob))    # the record is kept byte for byte
    conn.execute("DROP TABLE jobs_v1")


JOBS_TABLE = Table("jobs", 2, _JOBS_V2, {1: _jobs_1_to_2})
FOLLOW_TABLE = Table("follow", 1, """
CREATE TABLE follow (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    last_event_seq INTEGER NOT NULL
)""")
PLATE_TABLE = Table("plate", 1, """
CREATE TABLE plate (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    clear INTEGER NOT NULL
)""")


def _state_filter(states: Iterable[str]) -> tuple[str, tuple[str, ...]]:
    """A ``WHERE`` clause keeping ``states`` ("" and no parameters when none are given)."""
    wanted = tuple(sorted(set(states)))
    unknown = [st for st in wanted if st not in s.PRINT_JOB_STATES]
    if unknown:
        raise ValidationError(f"unknown job state {unknown[0]!r} (one of {list(s.PRINT_JOB_STATES)})",
                              field="states")
    if not wanted:
        return "", ()
    return f" WHERE state IN ({','.join('?' * len(wanted))})", wanted


class JobStore:
    """Job records in SQLite (see the module docstring). Thread-safe: every access holds the database's lock.

    ``writer``: the one writer of the records (the supervisor's); given, a change from any other thread while
    it runs raises ``OwnershipError`` (reads are free: they answer from the database as it is)."""

    def __init__(self, path: str | Path, writer: Writer | None = None) -> None:
        self.db = Database(path, (JOBS_TABLE, FOLLOW_TABLE, PLATE_TABLE), synchronous="FULL")
        self.writer = writer

    def _changing(self) -> None:
        if self.writer is not None:
            self.writer.require("a change of the job records")

    # Records --------------------------------------------------------------------------------

    def add(self, record: s.JobRecord) -> None:
        """A new job at the end of the queue."""
        self._changing()
        with self.db.write() as conn:
            row = conn.execute("SELECT COALESCE(MAX(position), 0) FROM jobs").fetchone()
            conn.execute("INSERT INTO jobs VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                         (record.job_id, float(row[0]) + 1.0, *_columns(record), codec.encode(record)))

    def save(self, *records: s.JobRecord, last_event_seq: int | None = None) -> None:
        """Write changed records (and, with them, how far the station's events were applied), all or none."""
        self._changing()
        with self.db.write() as conn:
            for rec in records:
                cur = conn.execute(f"UPDATE jobs SET {_COLUMNS} WHERE job_id = ?",
                                   (*_columns(rec), codec.encode(rec), rec.job_id))
                if cur.rowcount == 0:
                    raise NotFound(f"no job {rec.job_id}", job_id=rec.job_id)
            if last_event_seq is not None:
                conn.execute("INSERT OR REPLACE INTO follow VALUES (1, ?)", (int(last_event_seq),))

    def get(self, job_id: str) -> s.JobRecord:
        """The record of ``job_id`` (NotFound when unknown)."""
        with self.db.read() as conn:
            row = conn.execute("SELECT record FROM jobs WHERE job_id = ?", (job_id,)).fetchone()
        if row is None:
            raise NotFound(f"no job {job_id}", job_id=job_id)
        return codec.decode(row[0], s.JobRecord)

    def all(self) -> list[s.JobRecord]:
        """Every record, in queue order (which is submission order unless reordered). Decodes them all:
        prefer :meth:`page`, :meth:`in_states` or :meth:`latest`."""
        with self.db.read() as conn:
            rows = conn.execute("SELECT record FROM jobs ORDER BY position").fetchall()
        return [codec.decode(r[0], s.JobRecord) for r in rows]

    def page(self, offset: int = 0, limit: int = 100, states: Iterable[str] = ()) -> tuple[list[s.JobRecord], int]:
        """``limit`` records from the ``offset``-th (0-based) in queue order, of ``states`` only when given,
        and how many there are in all (of those states): one consistent read."""
        if offset < 0 or limit < 0:
            raise ValidationError(f"offset and limit must be >= 0, got {offset} and {limit}",
                                  field="offset" if offset < 0 else "limit")
        where, params = _state_filter(states)
        with self.db.read() as conn:
            total = int(conn.execute(f"SELECT COUNT(*) FROM jobs{where}", params).fetchone()[0])
            rows = conn.execute(f"SELECT record FROM jobs{where} ORDER BY position LIMIT ? OFFSET ?",
                                (*params, int(limit), int(offset))).fetchall()
        return [codec.decode(r[0], s.JobRecord) for r in rows], total

    def in_states(self, states: Iterable[str]) -> list[s.JobRecord]:
        """The records in ``states``, in queue order (none when ``states`` is empty)."""
        where, params = _state_filter(states)
        if not params:
            return []
        with self.db.read() as conn:
            rows = conn.execute(f"SELECT record FROM jobs{where} ORDER BY position", params).fetchall()
        return [codec.decode(r[0], s.JobRecord) for r in rows]

    def latest(self) -> s.JobRecord | None:
        """The record changed last (greatest ``updated_s``; None when there are no jobs)."""
        with self.db.read() as conn:
            row = conn.execute("SELECT record FROM jobs ORDER BY updated_s DESC LIMIT 1").fetchone()
        return None if row is None else codec.decode(row[0], s.JobRecord)

    def count(self, states: Iterable[str] = ()) -> int:
        """How many jobs there are (in ``states``, when given)."""
        where, params = _state_filter(states)
        with self.db.read() as conn:
            return int(conn.execute(f"SELECT COUNT(*) FROM jobs{where}", params).fetchone()[0])

    def remove(self, job_id: str) -> None:
        """Forget ``job_id``."""
        self._changing()
        with self.db.write() as conn:
            if conn.execute("DELETE FROM jobs WHERE job_id = ?", (job_id,)).rowcount == 0:
                raise NotFound(f"no job {job_id}", job_id=job_id)

    def move(self, job_id: str, index: int, among: list[str]) -> None:
        """Put ``job_id`` at ``index`` (0 = first) of the ordered ids ``among`` (the waiting queue)."""
        if job_id not in among:
            raise ValidationError(f"job {job_id} is not waiting in the queue", field="job_id", job_id=job_id)
        if not 0 <= index < len(among):
            raise ValidationError(f"position {index} outside the queue of {len(among)} jobs", field="position")
        order = [j for j in among if j != job_id]
        order.insert(index, job_id)
        self._changing()
        with self.db.write() as conn:
            slots = sorted(float(r[0]) for r in conn.execute(
                f"SELECT position FROM jobs WHERE job_id IN ({','.join('?' * len(among))})", among))
            for pos, jid in zip(slots, order, strict=True):
                conn.execute("UPDATE jobs SET position = ? WHERE job_id = ?", (pos, jid))

    # Following the station, and the plate --------------------------------------------------------

    def last_event_seq(self) -> int:
        """The station event last applied (0 when none)."""
        with self.db.read() as conn:
            row = conn.execute("SELECT last_event_seq FROM follow WHERE id = 1").fetchone()
        return 0 if row is None else int(row[0])

    def plate_clear(self) -> bool:
        """Whether the operator confirmed the plate is clear since the last print began (initially yes)."""
        with self.db.read() as conn:
            row = conn.execute("SELECT clear FROM plate WHERE id = 1").fetchone()
        return True if row is None else bool(row[0])

    def set_plate_clear(self, clear: bool) -> None:
        self._changing()
        with self.db.write() as conn:
            conn.execute("INSERT OR REPLACE INTO plate VALUES (1, ?)", (int(clear),))

    def close(self) -> None:
        self.db.close()
