"""Small typed results a service keeps by key (slice results, plan summaries), durable across restarts."""
from __future__ import annotations

import threading
from pathlib import Path
from typing import TypeVar

from fabric.wire import codec
from fabric.store.sqlite import open_db

__all__ = ["RecordStore"]

T = TypeVar("T")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS records (
    kind TEXT NOT NULL,
    key TEXT NOT NULL,
    payload BLOB NOT NULL,
    PRIMARY KEY (kind, key)
);
"""


class RecordStore:
    """Schema messages by (kind, key) in SQLite; thread-safe."""

    def __init__(self, path: str | Path) -> None:
        self._lock = threading.Lock()
        self._db = open_db(path, _SCHEMA, synchronous="FULL")

    def put(self, kind: str, key: str, msg: object) -> None:
        """Keep ``msg`` (a schema instance) under ``(kind, key)``, replacing what was there."""
        with self._lock, self._db:
            self._db.execute("INSERT OR REPLACE INTO records VALUES (?, ?, ?)", (kind, key, codec.encode(msg)))

    def get(self, kind: str, key: str, msg_type: type[T]) -> T | None:
        """The message kept under ``(kind, key)``, or None."""
        row = self._db.execute("SELECT payload FROM records WHERE kind = ? AND key = ?", (kind, key)).fetchone()
        return None if row is None else codec.decode(row[0], msg_type)

    def close(self) -> None:
        with self._lock:
            self._db.close()
