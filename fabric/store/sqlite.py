"""Opening a SQLite database the way every store here uses it: WAL journal, a busy timeout, a schema."""
from __future__ import annotations

import sqlite3
from pathlib import Path

__all__ = ["open_db"]

BUSY_TIMEOUT_MS = 10_000


def open_db(path: str | Path, schema: str, *, synchronous: str = "NORMAL") -> sqlite3.Connection:
    """A connection to ``path`` in WAL mode with ``schema`` applied (idempotent ``CREATE ... IF NOT EXISTS``).

    ``synchronous``: ``FULL`` fsyncs every commit (survives power loss);
    ``NORMAL`` in WAL mode survives any process crash and fsyncs at
    checkpoints, which is what frequent writers (events, station checkpoints)
    use. The connection may be used from several threads; callers serialise
    access with their own lock.
    """
    if synchronous not in ("NORMAL", "FULL"):
        raise ValueError(f"synchronous must be NORMAL or FULL, got {synchronous!r}")
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    db = sqlite3.connect(str(path), timeout=BUSY_TIMEOUT_MS / 1000.0, check_same_thread=False,
                         isolation_level="DEFERRED")
    db.execute("PRAGMA journal_mode=WAL")
    db.execute(f"PRAGMA synchronous={synchronous}")
    db.execute(f"PRAGMA busy_timeout={BUSY_TIMEOUT_MS}")
    db.executescript(schema)
    db.commit()
    return db
