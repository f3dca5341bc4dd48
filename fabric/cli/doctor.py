"""``fabric-cli doctor``: check every store of a cell's services; set aside and recover a damaged one.

For each service folder of the cell (``<data-dir>/<cell>/<service>``) and each database in it (the
supervisor's ``jobs.sqlite``, the station's ``station.sqlite``, every service's ``records.sqlite`` and
artifact index ``artifacts/index.sqlite``), the doctor checks the file read-only (``PRAGMA quick_check``,
the tables' versions), then opens a sound one through its real store class, as the service does at start
(migrations included). A file found damaged is:

1. moved aside, with its ``-wal`` and ``-shm``, to ``<name>.damaged-YYYYmmdd-HHMMSS`` next to it (kept
   as it was, for a backup or a closer look);
2. read as far as it can be: every table SQLite can still find, every row it can still read (a scan
   that meets a damaged page goes on past it by row id, and reads the table from its other end too);
3. written into a fresh database made by the store class (current tables and indexes), rows checked
   as the store reads them (a job record must decode); a file from an older release is rebuilt in its
   own schema and migrated by the store class;
4. put in place of the damaged one and opened once more through the store class.

Nothing readable (a file overwritten with garbage): the fresh database starts empty. The doctor
holds each service's folder lock while it works, so it never touches the files of a running service
(it then only checks them, read-only). ``--check`` only reports. A file written by a newer release
is left alone (run that release). Exit code 0 when every store can be opened now, 1 otherwise.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sqlite3
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["StoreFile", "check_cell", "recover_file", "register"]


def register(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    from fabric.wire.config import add_data_argument
    p = sub.add_parser("doctor", parents=[common],
                       help="check the cell's stores; set a damaged one aside (a copy is kept) and recover it",
                       description="Check every database of the cell's services (stop them first to repair): "
                                   "a damaged file is moved aside as NAME.damaged-TIME (kept), what can still be "
                                   "read is recovered into a fresh one. Exit 1 when a store is left unusable.")
    add_data_argument(p)
    p.add_argument("--check", action="store_true", help="only check and report; change nothing")
    p.set_defaults(local=cmd_doctor)


# --- the stores of each service --------------------------------------------------------------------

@dataclass(frozen=True)
class StoreFile:
    """One database of a service: where it lives in the service's folder, how its store class makes an
    empty one at a path, how it opens one in its place (and closes it again), how its rows are checked."""

    service: str
    rel: str
    create: Callable[[Path], None]
    open_in_place: Callable[[Path], None]
    tables: tuple[Any, ...] = ()                       # its ``fabric.store.sqlite.Table``s (versions)
    check_rows: Callable[[sqlite3.Connection], dict[str, int]] | None = None


def _store_files(service: str) -> list[StoreFile]:
    from fabric.store import artifacts
    from fabric.store.jobs import FOLLOW_TABLE, JOBS_TABLE, PLATE_TABLE, JobStore
    from fabric.store.records import RECORDS_TABLE, RecordStore
    from fabric.store.sqlite import open_db
    from fabric.store.station import STATION_TABLES, StationStore

    def through(store_type: type) -> Callable[[Path], None]:
        return lambda path: store_type(path).close()

    files = []
    if service == "supervisor":
        files.append(StoreFile(service, "jobs.sqlite", through(JobStore), through(JobStore),
                               (JOBS_TABLE, FOLLOW_TABLE, PLATE_TABLE), _check_jobs))
    if service == "station":
        files.append(StoreFile(service, "station.sqlite", through(StationStore), through(StationStore),
                               STATION_TABLES, _check_station))
    files.append(StoreFile(service, "records.sqlite", through(RecordStore), through(RecordStore), (RECORDS_TABLE,)))
    # the artifact index: made with its schema; opened in place by the store, which also re-indexes the files
    files.append(StoreFile(service, "artifacts/index.sqlite",
                           lambda path: open_db(path, artifacts.INDEX_SCHEMA, synchronous="FULL").close(),
                           lambda path: artifacts.ArtifactStore(path.parent).close()))
    return files


def _check_jobs(conn: sqlite3.Connection) -> dict[str, int]:
    """Drop job rows whose record does not decode (the supervisor would fail on them)."""
    from fabric import schemas as s
    from fabric.wire import codec
    from fabric.wire.errors import FabricError
    bad = []
    for job_id, blob in conn.execute("SELECT job_id, record FROM jobs").fetchall():
        try:
            codec.decode(blob, s.JobRecord)
        except (FabricError, ValueError, TypeError):
            bad.append(job_id)
    conn.executemany("DELETE FROM jobs WHERE job_id = ?", [(j,) for j in bad])
    return {"jobs": len(bad)} if bad else {}


def _check_station(conn: sqlite3.Connection) -> dict[str, int]:
    """Drop events that do not decode, and bead chunks after the first gap (beads are one sequence)."""
    from fabric import schemas as s
    from fabric.wire import codec
    from fabric.wire.errors import FabricError
    dropped: dict[str, int] = {}
    bad = []
    for seq, blob in conn.execute("SELECT seq, payload FROM events").fetchall():
        try:
            codec.decode(blob, s.Event)
        except (FabricError, ValueError, TypeError):
            bad.append(seq)
    conn.executemany("DELETE FROM events WHERE seq = ?", [(q,) for q in bad])
    if bad:
        dropped["events"] = len(bad)
    expected = 0
    gap: list[int] = []
    for first, count in conn.execute("SELECT first, count FROM beads ORDER BY first").fetchall():
        if gap or first != expected:
            gap.append(first)
        expected = first + count
    conn.executemany("DELETE FROM beads WHERE first = ?", [(f,) for f in gap])
    if gap:
        dropped["beads"] = len(gap)
    return dropped


# --- reading what a damaged file still holds -------------------------------------------------------

@dataclass
class _Salvage:
    """What could be read from a damaged file: its schema, each table's rows, whether rows were lost."""

    master: list[tuple[str, str, str | None]] = field(default_factory=list)   # (type, name, sql)
    tables: dict[str, tuple[list[str], list[tuple]]] = field(default_factory=dict)
    versions: dict[str, int] | None = None
    incomplete: set[str] = field(default_factory=set)
    unreadable: str = ""                         # why nothing at all could be read


def _q(name: str) -> str:
    return '"' + name.replace('"', '""') + '"'


def _read_rows(conn: sqlite3.Connection, table: str, cols: list[str]) -> tuple[list[tuple], bool]:
    """Every row of ``table`` SQLite can still read, in row id order, and whether some could not be."""
    select = f"SELECT rowid, {', '.join(_q(c) for c in cols)} FROM {_q(table)}"
    rows: dict[int, tuple] = {}
    lost = False
    last: int | None = None
    for _ in range(100_000):                     # each round moves past at least one row id
        try:
            cur = conn.execute(select + (" WHERE rowid > ?" if last is not None else "") + " ORDER BY rowid",
                               (last,) if last is not None else ())
            for r in cur:
                rows[r[0]] = tuple(r[1:])
                last = r[0]
            break
        except sqlite3.DatabaseError:
            lost = True
        try:                                     # the next row ids, without reading the rows themselves
            ids = [r[0] for r in conn.execute(f"SELECT rowid FROM {_q(table)} WHERE rowid > ? ORDER BY rowid "
                                              f"LIMIT 64", (last if last is not None else -(2 ** 63),))]
        except sqlite3.DatabaseError:
            break                                # the table's tree is broken from here: read it from its end
        if not ids:
            break
        for rid in ids:                          # one by one: a row whose own data is damaged is skipped
            try:
                r = conn.execute(select + " WHERE rowid = ?", (rid,)).fetchone()
                if r is not None:
                    rows[r[0]] = tuple(r[1:])
            except sqlite3.DatabaseError:
                pass
        last = ids[-1]
    try:                                         # from the other end, down to where the first scan got
        for r in conn.execute(select + " ORDER BY rowid DESC"):
            if r[0] in rows or (last is not None and r[0] <= last):
                break
            rows[r[0]] = tuple(r[1:])
    except sqlite3.DatabaseError:
        lost = True
    return [rows[k] for k in sorted(rows)], lost


def _mend_header(path: Path) -> None:
    """Make the header of ``path`` (a scratch copy) state the pages the file really has: SQLite trusts the
    size written there, and refuses a truncated file outright (every query: "malformed") until it matches."""
    with open(path, "r+b") as fh:
        head = fh.read(100)
        if len(head) < 100 or not head.startswith(b"SQLite format 3\x00"):
            return                                   # not SQLite at all: nothing to mend
        page = int.from_bytes(head[16:18], "big")
        page = 65536 if page == 1 else page
        if page < 512 or page & (page - 1):
            return
        size = os.fstat(fh.fileno()).st_size
        if size % page:                              # a page cut in the middle: its missing end reads as zeros
            fh.truncate(size + page - size % page)
            size += page - size % page
        pages = size // page
        if int.from_bytes(head[28:32], "big") != pages:
            fh.seek(28)
            fh.write(pages.to_bytes(4, "big"))


def _salvage(path: Path) -> _Salvage:
    """Read what ``path`` (a scratch copy: SQLite may write to it) still holds."""
    out = _Salvage()
    _mend_header(path)
    conn = sqlite3.connect(str(path), isolation_level=None)
    try:
        try:
            out.master = [(str(t), str(n), s) for t, n, s in
                          conn.execute("SELECT type, name, sql FROM sqlite_master").fetchall()]
        except sqlite3.DatabaseError as exc:
            out.unreadable = str(exc)
            return out
        for kind, name, _ in out.master:
            if kind != "table" or name.startswith("sqlite_"):
                continue
            try:
                cols = [str(r[1]) for r in conn.execute(f"PRAGMA table_info({_q(name)})")]
            except sqlite3.DatabaseError:
                out.incomplete.add(name)
                continue
            rows, lost = _read_rows(conn, name, cols)
            out.tables[name] = (cols, rows)
            if lost:
                out.incomplete.add(name)
        if "schema_versions" in out.tables and "schema_versions" not in out.incomplete:
            cols, rows = out.tables["schema_versions"]
            out.versions = {str(r[cols.index("name")]): int(r[cols.index("version")]) for r in rows}
    finally:
        conn.close()
    return out


def _columns(conn: sqlite3.Connection, table: str) -> list[str]:
    return [str(r[1]) for r in conn.execute(f"PRAGMA table_info({_q(table)})")]


def _insert(conn: sqlite3.Connection, table: str, cols: list[str], rows: list[tuple]) -> int:
    """Insert ``rows`` (of ``cols``), skipping the ones the table refuses; how many went in."""
    sql = f"INSERT OR IGNORE INTO {_q(table)} ({', '.join(_q(c) for c in cols)}) VALUES ({', '.join('?' * len(cols))})"
    n = 0
    for row in rows:
        try:
            n += conn.execute(sql, row).rowcount
        except sqlite3.Error:
            pass
    return n


def _rebuild_current(sf: StoreFile, new: Path, salvage: _Salvage) -> dict[str, int]:
    """A fresh database of the store's current schema at ``new``, with every salvaged row it takes."""
    sf.create(new)
    counts: dict[str, int] = {}
    conn = sqlite3.connect(str(new), isolation_level=None)
    try:
        conn.execute("BEGIN")
        fresh = {str(r[0]) for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        for table, (cols, rows) in salvage.tables.items():
            if table == "schema_versions" or table not in fresh:
                continue
            present = set(_columns(conn, table))
            keep = [c for c in cols if c in present]
            idx = [cols.index(c) for c in keep]
            counts[table] = _insert(conn, table, keep, [tuple(r[i] for i in idx) for r in rows])
        conn.execute("COMMIT")
    finally:
        conn.close()
    return counts


def _rebuild_as_was(sf: StoreFile, new: Path, salvage: _Salvage) -> dict[str, int]:
    """The salvaged file rebuilt in its own (older) schema at ``new``, then migrated by the store class."""
    counts: dict[str, int] = {}
    conn = sqlite3.connect(str(new), isolation_level=None)
    try:
        conn.execute("BEGIN")
        for kind, name, sql in salvage.master:
            if kind == "table" and sql and not name.startswith("sqlite_"):
                conn.execute(sql)
                cols, rows = salvage.tables.get(name, ([], []))
                counts[name] = _insert(conn, name, cols, rows) if cols else 0
        for kind, _, sql in salvage.master:
            if kind == "index" and sql:
                try:
                    conn.execute(sql)
                except sqlite3.Error:
                    pass                      # rows that break it: the migration or the store makes it again
        conn.execute("COMMIT")
    finally:
        conn.close()
    counts.pop("schema_versions", None)
    sf.create(new)                            # migrates it (or raises: then the current schema is used)
    return counts


def _older(sf: StoreFile, salvage: _Salvage) -> bool:
    """Whether the damaged file was written by an older release (a table at an older version)."""
    if not sf.tables or salvage.versions is None:
        return False
    return any(salvage.versions.get(t.name, t.version) < t.version for t in sf.tables if t.name in salvage.tables)


def _aside_name(path: Path, stamp: str) -> Path:
    aside = path.with_name(f"{path.name}.damaged-{stamp}")
    k = 2
    while any(Path(f"{aside}{sfx}").exists() for sfx in ("", "-wal", "-shm")):
        aside = path.with_name(f"{path.name}.damaged-{stamp}-{k}")
        k += 1
    return aside


def recover_file(sf: StoreFile, path: Path) -> dict[str, Any]:
    """Move the damaged ``path`` aside (kept, with its -wal and -shm) and put a fresh database holding
    what could be read from it in its place. Returns what was done."""
    aside = _aside_name(path, time.strftime("%Y%m%d-%H%M%S"))
    for sfx in ("", "-wal", "-shm"):
        src = Path(f"{path}{sfx}")
        if src.exists():
            os.replace(src, Path(f"{aside}{sfx}"))
    scratch = Path(tempfile.mkdtemp(prefix=".doctor-", dir=path.parent))
    try:
        copy = scratch / "damaged.sqlite"
        for sfx in ("", "-wal", "-shm"):
            if Path(f"{aside}{sfx}").exists():
                shutil.copyfile(f"{aside}{sfx}", f"{copy}{sfx}")
        salvage = _salvage(copy)
        new = scratch / path.name
        counts: dict[str, int] = {}
        how = "current"
        if salvage.tables and _older(sf, salvage):
            try:
                counts, how = _rebuild_as_was(sf, new, salvage), "migrated"
            except Exception:  # noqa: BLE001  (the older schema could not be rebuilt: the current one takes the rows)
                for sfx in ("", "-wal", "-shm"):
                    Path(f"{new}{sfx}").unlink(missing_ok=True)
                how = "current"
        if how == "current":
            counts = _rebuild_current(sf, new, salvage)
        dropped: dict[str, int] = {}
        if sf.check_rows is not None:
            conn = sqlite3.connect(str(new), isolation_level=None)
            try:
                conn.execute("BEGIN")
                dropped = sf.check_rows(conn)
                conn.execute("COMMIT")
            finally:
                conn.close()
            for table, n in dropped.items():
                counts[table] = max(0, counts.get(table, 0) - n)
        for sfx in ("-wal", "-shm"):          # the connections are closed: everything is in the main file
            Path(f"{new}{sfx}").unlink(missing_ok=True)
        os.replace(new, path)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    sf.open_in_place(path)                    # as the service will: it opens now
    return {"kept_as": str(aside), "recovered": counts, "incomplete": sorted(salvage.incomplete - {"schema_versions"}),
            "dropped": dropped, "unreadable": salvage.unreadable, "migrated": how == "migrated"}


# --- checking --------------------------------------------------------------------------------------

def _check_read_only(sf: StoreFile, path: Path) -> tuple[str, str]:
    """(status, problem) of ``path`` without changing it: quick_check and the tables' versions."""
    try:
        conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    except sqlite3.Error as exc:
        return "error", str(exc)
    try:
        rows = conn.execute("PRAGMA quick_check").fetchall()
        if [tuple(r) for r in rows] != [("ok",)]:
            return "damaged", "; ".join(str(r[0]) for r in rows[:3])
        if sf.tables:
            names = {str(r[0]) for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
            if "schema_versions" in names:
                found = {str(n): int(v) for n, v in conn.execute("SELECT name, version FROM schema_versions")}
                for t in sf.tables:
                    if found.get(t.name, 0) > t.version:
                        return "newer", (f"table {t.name} is at version {found[t.name]}, newer than this release "
                                         f"knows (v{t.version}): run the release that wrote it")
        return "ok", ""
    except sqlite3.DatabaseError as exc:
        if getattr(exc, "sqlite_errorname", "SQLITE_CORRUPT") in ("SQLITE_CORRUPT", "SQLITE_NOTADB"):
            return "damaged", str(exc)
        return "error", str(exc)
    finally:
        conn.close()


def _check_in_place(sf: StoreFile, path: Path) -> tuple[str, str]:
    """(status, problem) of ``path`` opened through its store class, as its service opens it."""
    from fabric.wire.errors import StoreError
    try:
        sf.open_in_place(path)
    except StoreError as err:
        reason = str(err.details.get("reason", ""))
        if reason == "damaged":
            return "damaged", str(err.details.get("problem") or err.message)
        return ("newer" if reason == "newer" else "error"), err.message
    return "ok", ""


def check_cell(data_root: Path, cell: str, repair: bool = True) -> list[dict[str, Any]]:
    """Check (and with ``repair``, repair) every store of ``cell`` under ``data_root``: one report per file."""
    from fabric.server.service import lock_dir
    from fabric.wire.errors import StateError
    from fabric.wire.keys import SERVICES
    reports = []
    for service in SERVICES:
        folder = data_root / cell / service
        present = [(sf, folder / sf.rel) for sf in _store_files(service) if (folder / sf.rel).exists()]
        if not present:
            continue
        lock, in_use = None, ""
        try:
            lock = lock_dir(folder, service, cell)
        except StateError as err:
            in_use = err.message
        try:
            for sf, path in present:
                report: dict[str, Any] = {"service": service, "file": str(path), "name": sf.rel}
                # read-only first: opening a damaged file read-write lets SQLite drop a -wal it cannot use,
                # and the copy kept must be the file as it was; a sound one is then opened as its service will
                status, problem = _check_read_only(sf, path)
                if status == "ok" and repair and lock is not None:
                    status, problem = _check_in_place(sf, path)
                report.update(status=status, problem=problem)
                if in_use:
                    report["in_use"] = in_use
                if status == "damaged" and repair and lock is not None:
                    try:
                        report.update(recover_file(sf, path), status="repaired")
                    except Exception as exc:  # noqa: BLE001  (said in the report; the file stays as it is now)
                        report.update(status="error", problem=f"repair failed: {type(exc).__name__}: {exc}")
                reports.append(report)
        finally:
            if lock is not None:
                lock.close()
    return reports


# --- the command -----------------------------------------------------------------------------------

def _line(r: dict[str, Any], doctor: str) -> str:
    head = f"  {r['service']:<11} {r['name']:<23} "
    status = r["status"]
    if status == "ok":
        return head + "ok" + (" (in use by its running service)" if r.get("in_use") else "")
    if status == "repaired":
        kept = Path(r["kept_as"]).name
        if r["unreadable"] or not any(r["recovered"].values()):
            what = f"nothing in it was readable ({r['unreadable']})" if r["unreadable"] else "no rows were readable"
            got = f"{what}: the {r['service']} starts with an empty store"
        else:
            parts = [f"{t} {n}" + (" (some rows unreadable)" if t in r["incomplete"] else "")
                     for t, n in r["recovered"].items() if n or t in r["incomplete"]]
            got = "recovered " + ", ".join(parts) + (" (migrated from an older release)" if r["migrated"] else "")
            if r["dropped"]:
                got += "; dropped " + ", ".join(f"{n} {t} that did not decode" for t, n in r["dropped"].items())
        return head + f"damaged ({r['problem']}): moved aside as {kept} (kept); {got}"
    if status == "damaged":
        if r.get("in_use"):
            return head + f"damaged ({r['problem']}), but in use: stop the {r['service']} first ({r['in_use']})"
        return head + f"damaged ({r['problem']}): run '{doctor}' (without --check) to set it aside and recover it"
    if status == "newer":
        return head + f"written by a newer release, left as it is: {r['problem']}"
    return head + f"cannot be opened, left as it is: {r['problem']}"


def cmd_doctor(a: argparse.Namespace) -> int:
    from fabric.cli.output import emit
    from fabric.services.host import doctor_command
    from fabric.wire.config import default_data_root
    root = Path(a.data_dir) if a.data_dir is not None else default_data_root()
    doctor = doctor_command(a.cell, a.data_dir)
    if not (root / a.cell).is_dir():
        emit({"cell": a.cell, "data_dir": str(root), "files": [], "ok": False,
              "message": f"no state of cell '{a.cell}' under {root}"}, a.json,
             lambda d: f"no state of cell '{a.cell}' under {root}: nothing to check (see --cell and --data-dir)")
        return 1
    reports = check_cell(root, a.cell, repair=not a.check)
    ok = all(r["status"] in ("ok", "repaired") for r in reports)
    repaired = sum(r["status"] == "repaired" for r in reports)

    def text(_: object) -> str:
        lines = [f"cell '{a.cell}' under {root}: {len(reports)} database(s)"]
        lines += [_line(r, doctor) for r in reports]
        if repaired:
            lines.append(f"repaired {repaired}; the cell can start ('fabric-cli up'; a running 'fabric-cli up' starts "
                         f"the stopped service again by itself)")
        elif ok:
            lines.append("every store is sound")
        return "\n".join(lines)

    emit({"cell": a.cell, "data_dir": str(root), "files": reports, "ok": ok}, a.json, text)
    return 0 if ok else 1
