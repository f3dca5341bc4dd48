"""One SQLite database of a store: one connection, one lock for every access, versioned tables.

A store declares its tables as :class:`Table` objects (name, current
version, the SQL that creates it at that version, and the migrations from
each older version) and opens them with :class:`Database`. On open:

1. ``PRAGMA quick_check``: a damaged file, or one that is not SQLite at all,
   is refused with a :class:`~fabric.wire.errors.StoreError` naming it, before
   anything is written to it;
2. WAL journal, the busy timeout and the store's ``synchronous`` setting;
3. in one transaction, every table is brought to its current version. The
   ``schema_versions`` table holds one row per table. A table that exists
   without a row was made by release 0.1.0 (which had no versions): it is
   version 1. Each older table is migrated one step at a time
   (``migrations[v]`` takes it from ``v`` to ``v + 1``); a table newer than
   this code is refused (a downgrade would lose or misread what the newer
   release wrote). A failure anywhere rolls the whole open back.

After that, every use goes through :meth:`Database.read` or
:meth:`Database.write`, which hold the one lock: no thread ever sees another
thread's half-done transaction, and no two threads interleave statements on
the connection. Rows must be fetched inside the ``with`` block.
"""
from __future__ import annotations

import sqlite3
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from fabric.wire.errors import FabricError, StoreError

__all__ = ["BUSY_TIMEOUT_MS", "Database", "Migration", "Table", "open_db", "run_script"]

BUSY_TIMEOUT_MS = 10_000
Migration = Callable[[sqlite3.Connection], None]
"""One migration step: given the connection inside the open's transaction, take a table from version
``v`` to ``v + 1`` (the key it is filed under in :attr:`Table.migrations` is ``v``)."""

_VERSIONS = """CREATE TABLE IF NOT EXISTS schema_versions (
    name TEXT PRIMARY KEY,
    version INTEGER NOT NULL
)"""
_DAMAGED_CODES = ("SQLITE_CORRUPT", "SQLITE_NOTADB")


@dataclass(frozen=True)
class Table:
    """A table of a store at its current ``version``: ``create`` makes it (with its indexes) from
    nothing; ``migrations[v]`` takes an existing table from version ``v`` to ``v + 1``."""

    name: str
    version: int
    create: str
    migrations: Mapping[int, Migration] = field(default_factory=dict)

    def __post_init__(self) -> None:
        missing = [v for v in range(1, self.version) if v not in self.migrations]
        if self.version < 1 or missing:
            raise ValueError(f"table {self.name} v{self.version}: no migration from version(s) {missing}")


class Database:
    """A SQLite file holding ``tables`` (see the module docstring). Safe to share between threads.

    ``synchronous``: ``FULL`` fsyncs every commit (survives power loss);
    ``NORMAL`` in WAL mode survives any process crash and fsyncs at
    checkpoints, which is what frequent writers (events, station checkpoints)
    use.
    """

    def __init__(self, path: str | Path, tables: Sequence[Table], *, synchronous: str = "NORMAL") -> None:
        if synchronous not in ("NORMAL", "FULL"):
            raise ValueError(f"synchronous must be NORMAL or FULL, got {synchronous!r}")
        self.path = Path(path)
        self.tables = tuple(tables)
        self.lock = threading.RLock()
        """Held by every read and write; a store holds it too around a write and the in-memory
        bookkeeping that must change only if that write is committed."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._conn = sqlite3.connect(str(self.path), timeout=BUSY_TIMEOUT_MS / 1000.0,
                                         check_same_thread=False, isolation_level=None)
        except sqlite3.Error as exc:
            raise self._error(exc) from exc
        try:
            self._conn.execute(f"PRAGMA busy_timeout={BUSY_TIMEOUT_MS}")
            self._check()
            self._conn.execute("PRAGMA journal_mode=WAL")
            self._conn.execute(f"PRAGMA synchronous={synchronous}")
            self._upgrade()
        except sqlite3.Error as exc:
            self._conn.close()
            raise self._error(exc) from exc
        except BaseException:
            self._conn.close()
            raise

    # Access ----------------------------------------------------------------------------------

    @contextmanager
    def read(self) -> Iterator[sqlite3.Connection]:
        """The connection, for reads that see one consistent state (a read transaction under the lock)."""
        with self.lock:
            nested = self._conn.in_transaction
            if not nested:
                self._conn.execute("BEGIN")
            try:
                yield self._conn
            finally:
                if not nested:
                    self._conn.execute("COMMIT")

    @contextmanager
    def write(self) -> Iterator[sqlite3.Connection]:
        """The connection inside a transaction: committed when the block ends, rolled back if it raises."""
        with self.lock:
            if self._conn.in_transaction:
                raise RuntimeError(f"{self.path}: a write inside another read or write of the same database")
            self._conn.execute("BEGIN IMMEDIATE")
            try:
                yield self._conn
                self._conn.execute("COMMIT")
            except BaseException:
                if self._conn.in_transaction:     # the block raised, or the commit failed (a full disk)
                    self._conn.execute("ROLLBACK")
                raise

    def versions(self) -> dict[str, int]:
        """Every table's version, as recorded in the file."""
        with self.read() as conn:
            return {str(n): int(v) for n, v in conn.execute("SELECT name, version FROM schema_versions")}

    def close(self) -> None:
        with self.lock:
            self._conn.close()

    # Opening ----------------------------------------------------------------------------------

    def _check(self) -> None:
        """Refuse a damaged file before touching it."""
        rows = self._conn.execute("PRAGMA quick_check").fetchall()
        if [tuple(r) for r in rows] != [("ok",)]:
            problems = "; ".join(str(r[0]) for r in rows[:3])
            raise self._damaged(problems)

    def _upgrade(self) -> None:
        """Create missing tables, migrate old ones, refuse newer ones: all in one transaction."""
        with self.write() as conn:
            conn.execute(_VERSIONS)
            known = {str(n): int(v) for n, v in conn.execute("SELECT name, version FROM schema_versions")}
            present = {str(r[0]) for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
            for table in self.tables:
                version = known.get(table.name, 1 if table.name in present else 0)
                if version > table.version:
                    raise StoreError(f"{self.path}: table {table.name} is at version {version}, newer than this "
                                     f"release knows (v{table.version}): it was written by a newer am-fabric; "
                                     f"run that release, or move the file aside to start afresh",
                                     file=str(self.path), table=table.name, version=version,
                                     supported=table.version, reason="newer")
                if version == 0:
                    run_script(conn, table.create)
                else:
                    self._migrate(conn, table, version)
                if known.get(table.name) != table.version:
                    conn.execute("INSERT OR REPLACE INTO schema_versions VALUES (?, ?)", (table.name, table.version))

    def _migrate(self, conn: sqlite3.Connection, table: Table, version: int) -> None:
        for v in range(version, table.version):
            try:
                table.migrations[v](conn)
            except StoreError:
                raise
            except FabricError as exc:           # a row that does not decode, say
                raise StoreError(f"{self.path}: cannot migrate table {table.name} from version {v} to {v + 1}: "
                                 f"{exc.message}; the file is unchanged", file=str(self.path), table=table.name,
                                 version=v, reason="migration") from exc

    def _damaged(self, what: str) -> StoreError:
        return _damaged(self.path, what)

    def _error(self, exc: sqlite3.Error) -> StoreError:
        return _open_error(self.path, exc)


def _damaged(path: Path, what: str) -> StoreError:
    return StoreError(f"{path} is damaged ({what}): move it aside (or restore it from a backup) and "
                      f"start again; the service then begins with an empty store", file=str(path),
                      reason="damaged", problem=what)


def _open_error(path: Path, exc: sqlite3.Error) -> StoreError:
    if getattr(exc, "sqlite_errorname", "") in _DAMAGED_CODES:
        return _damaged(path, str(exc))
    return StoreError(f"cannot open {path}: {exc}", file=str(path), reason="open")


def run_script(conn: sqlite3.Connection, script: str) -> None:
    """Run ``;``-separated statements (DDL without ``;`` inside: no triggers, no string literals holding
    one) inside the current transaction; ``executescript`` would commit it first."""
    for statement in script.split(";"):
        if statement.strip():
            conn.execute(statement)


def open_db(path: str | Path, schema: str, *, synchronous: str = "NORMAL") -> sqlite3.Connection:
    """A bare connection to ``path`` in WAL mode with ``schema`` applied (idempotent ``CREATE ... IF NOT
    EXISTS``), for a store not yet on :class:`Database` (the artifact index). The caller serialises every
    use of the connection, reads included, with its own lock."""
    if synchronous not in ("NORMAL", "FULL"):
        raise ValueError(f"synchronous must be NORMAL or FULL, got {synchronous!r}")
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    db = sqlite3.connect(str(path), timeout=BUSY_TIMEOUT_MS / 1000.0, check_same_thread=False,
                         isolation_level="DEFERRED")
    try:            # a damaged file is refused as Database refuses it: a StoreError naming it
        rows = db.execute("PRAGMA quick_check").fetchall()
        if [tuple(r) for r in rows] != [("ok",)]:
            raise _damaged(Path(path), "; ".join(str(r[0]) for r in rows[:3]))
        db.execute("PRAGMA journal_mode=WAL")
        db.execute(f"PRAGMA synchronous={synchronous}")
        db.execute(f"PRAGMA busy_timeout={BUSY_TIMEOUT_MS}")
        db.executescript(schema)
        db.commit()
    except StoreError:
        db.close()
        raise
    except sqlite3.Error as exc:
        db.close()
        raise _open_error(Path(path), exc) from exc
    return db
