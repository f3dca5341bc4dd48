"""Small typed results a service keeps by key (slice results, plan summaries), durable across restarts.

One table, ``records`` v1 (as in release 0.1.0; see :mod:`fabric.store.sqlite`)."""
from __future__ import annotations

from pathlib import Path
from typing import TypeVar

from fabric.store.sqlite import Database, Table
from fabric.wire import codec

__all__ = ["RECORDS_TABLE", "RecordStore"]

T = TypeVar("T")

RECORDS_TABLE = Table("records", 1, """
CREATE TABLE records (
    kind TEXT NOT NULL,
    key TEXT NOT NULL,
    payload BLOB NOT NULL,
    PRIMARY KEY (kind, key)
)""")


class RecordStore:
    """Schema messages by (kind, key) in SQLite; thread-safe (every access holds the database's lock)."""

    def __init__(self, path: str | Path) -> None:
        self.db = Database(path, (RECORDS_TABLE,), synchronous="FULL")

    def put(self, kind: str, key: str, msg: object) -> None:
        """Keep ``msg`` (a schema instance) under ``(kind, key)``, replacing what was there."""
        with self.db.write() as conn:
            conn.execute("INSERT OR REPLACE INTO records VALUES (?, ?, ?)", (kind, key, codec.encode(msg)))

    def get(self, kind: str, key: str, msg_type: type[T]) -> T | None:
        """The message kept under ``(kind, key)``, or None."""
        with self.db.read() as conn:
            row = conn.execute("SELECT payload FROM records WHERE kind = ? AND key = ?", (kind, key)).fetchone()
        return None if row is None else codec.decode(row[0], msg_type)

    def close(self) -> None:
        self.db.close()
