"""The station's durable state: the event log, the twin's checkpoint, its beads and the clock mark.

Three things are written, at three rates, so that a station killed at any
instant comes back exactly:

- every simulation tick, in one transaction: the events of that tick (the
  lossless stream, so ``seq`` goes on across restarts) and the *clock mark*,
  the simulated time reached. Both are small. At rest (nothing moves, no
  print runs) a tick without events moves the mark at most once a second
  (:mod:`fabric.store.journal`): a restore replays only the clock and the
  heaters from there;
- at a bounded cadence and on every command: the *checkpoint*, the twin's
  whole state without its beads (see :mod:`fabric.sim.state`) plus what the
  station needs beside it (program id, job id, real-time factor);
- with each checkpoint, the beads deposited since the previous one, appended
  as a chunk: a million-bead print is never rewritten whole.

On restart the station restores the checkpoint and advances the twin to the
clock mark: the twin is deterministic, so it re-deposits exactly what was
deposited after the checkpoint, and the events it re-emits are the ones
already in the log.

Tables, all at version 1 as in release 0.1.0 (see :mod:`fabric.store.sqlite`):
``events``, ``clock``, ``checkpoint``, ``beads``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fabric import schemas as s
from fabric.store.sqlite import Database, Table
from fabric.wire import codec

__all__ = ["STATION_TABLES", "Checkpoint", "StationStore"]

STATION_TABLES = (
    Table("events", 1, """
CREATE TABLE events (
    seq INTEGER PRIMARY KEY,
    kind TEXT NOT NULL,
    payload BLOB NOT NULL
);
CREATE INDEX events_kind ON events (kind, seq)"""),
    Table("clock", 1, """
CREATE TABLE clock (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    t_sim_s REAL NOT NULL
)"""),
    Table("checkpoint", 1, """
CREATE TABLE checkpoint (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    epoch TEXT NOT NULL,
    payload BLOB NOT NULL
)"""),
    Table("beads", 1, """
CREATE TABLE beads (
    first INTEGER PRIMARY KEY,
    count INTEGER NOT NULL,
    payload BLOB NOT NULL
)"""),
)


@dataclass
class Checkpoint:
    """What a restarted station restores: the saved state, the beads up to it, the clock mark."""

    state: dict[str, Any]
    beads: dict[str, np.ndarray]
    t_mark_s: float


class StationStore:
    """The station's SQLite database (WAL; see the module docstring). Thread-safe: every access holds the
    database's lock, and so does the count of beads stored (changed only once its write is committed)."""

    def __init__(self, path: str | Path, keep_events: int = 200_000) -> None:
        self.path = Path(path)
        self.keep_events = int(keep_events)
        self.db = Database(self.path, STATION_TABLES, synchronous="NORMAL")
        with self.db.read() as conn:
            self._stored_beads = int(conn.execute("SELECT COALESCE(SUM(count), 0) FROM beads").fetchone()[0])
            row = conn.execute("SELECT epoch FROM checkpoint WHERE id = 1").fetchone()
        self._epoch: str | None = None if row is None else str(row[0])
        self._since_prune = 0

    # Events and the clock -------------------------------------------------------------------

    def record_tick(self, events: list[s.Event], t_sim_s: float) -> None:
        """Append this tick's events and move the clock mark, in one transaction."""
        with self.db.write() as conn:
            if events:
                conn.executemany("INSERT OR REPLACE INTO events VALUES (?, ?, ?)",
                                 [(e.seq, e.kind, codec.encode(e)) for e in events])
                self._since_prune += len(events)
            conn.execute("INSERT OR REPLACE INTO clock VALUES (1, ?)", (float(t_sim_s),))
            if self._since_prune > 1000:
                self._since_prune = 0
                conn.execute("DELETE FROM events WHERE seq <= (SELECT MAX(seq) FROM events) - ?",
                             (self.keep_events,))

    def last_seq(self) -> int:
        """The sequence number of the last event recorded (0 when none)."""
        with self.db.read() as conn:
            return int(conn.execute("SELECT COALESCE(MAX(seq), 0) FROM events").fetchone()[0])

    def events(self, since_seq: int = 0, limit: int = 10_000, kinds: list[str] | None = None) -> list[s.Event]:
        """Recorded events with ``seq > since_seq`` (of ``kinds`` only, when given), oldest first."""
        with self.db.read() as conn:
            if kinds:
                marks = ",".join("?" * len(kinds))
                rows = conn.execute(f"SELECT payload FROM events WHERE seq > ? AND kind IN ({marks}) ORDER BY seq "
                                    f"LIMIT ?", (int(since_seq), *kinds, int(limit))).fetchall()
            else:
                rows = conn.execute("SELECT payload FROM events WHERE seq > ? ORDER BY seq LIMIT ?",
                                    (int(since_seq), int(limit))).fetchall()
        return [codec.decode(r[0], s.Event) for r in rows]

    def clock_mark(self) -> float | None:
        """The simulated time last recorded (None before the first tick)."""
        with self.db.read() as conn:
            row = conn.execute("SELECT t_sim_s FROM clock WHERE id = 1").fetchone()
        return None if row is None else float(row[0])

    # Checkpoints ------------------------------------------------------------------------------

    def save_checkpoint(self, state: dict[str, Any], epoch: str, beads: Any) -> None:
        """Save ``state`` (a dict of plain values, msgpack-able) and the beads of ``beads`` (a
        :class:`~fabric.sim.deposition.Deposition`) not stored yet. ``epoch`` names the job the beads
        belong to: a new epoch (a new job) starts the bead record afresh."""
        with self.db.lock:                           # the count below changes only if the write commits
            with self.db.write() as conn:
                stored = 0 if epoch != self._epoch or len(beads) < self._stored_beads else self._stored_beads
                if stored == 0:
                    conn.execute("DELETE FROM beads")
                n = len(beads)
                if n > stored:
                    chunk = beads.to_arrays(stored)
                    conn.execute("INSERT INTO beads VALUES (?, ?, ?)", (stored, n - stored, codec.pack(chunk)))
                conn.execute("INSERT OR REPLACE INTO checkpoint VALUES (1, ?, ?)", (epoch, codec.pack(state)))
            self._stored_beads, self._epoch = n, epoch

    def load(self) -> Checkpoint | None:
        """The last checkpoint with its beads and the clock mark (None when nothing was saved)."""
        with self.db.read() as conn:                 # the checkpoint, its beads and the mark of one moment
            row = conn.execute("SELECT payload FROM checkpoint WHERE id = 1").fetchone()
            if row is None:
                return None
            chunks = [r[0] for r in conn.execute("SELECT payload FROM beads ORDER BY first").fetchall()]
            mark = conn.execute("SELECT t_sim_s FROM clock WHERE id = 1").fetchone()
        state = codec.unpack(row[0])
        arrays = [codec.unpack(c) for c in chunks]
        beads = {k: np.concatenate([a[k] for a in arrays]) for k in arrays[0]} if arrays else {}
        return Checkpoint(state, beads, float(mark[0]) if mark is not None else 0.0)

    def close(self) -> None:
        self.db.close()
