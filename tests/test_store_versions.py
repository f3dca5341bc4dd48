"""Versioned stores: release 0.1.0's databases migrated, newer and damaged files refused, every access
serialised, job pages and queries, and pagination of supervisor/jobs over real Zenoh."""
from __future__ import annotations

import hashlib
import shutil
import sqlite3
import threading
from pathlib import Path

import pytest

from fabric import schemas as s
from fabric.cli.job_cmds import _list_text
from fabric.client import Client
from fabric.services.supervisor import SupervisorService
from fabric.store.jobs import JobStore
from fabric.store.records import RecordStore
from fabric.store.station import StationStore
from fabric.wire import codec
from fabric.wire.errors import DecodeError, StoreError, ValidationError

pytestmark = pytest.mark.timeout(60)

RELEASE_0_1_0 = Path(__file__).parent / "data" / "release-0.1.0"
QUEUE_0_1_0 = ["000000000000", "000000000001", "000000000002", "000000000004", "000000000003"]


def release_copy(tmp_path: Path, name: str) -> Path:
    """A copy of release 0.1.0's ``name`` to migrate (the committed file is never opened for writing)."""
    dst = tmp_path / name
    shutil.copyfile(RELEASE_0_1_0 / name, dst)
    return dst


def dump(path: Path) -> list[str]:
    """Every schema statement and row of the database at ``path``."""
    conn = sqlite3.connect(path)
    try:
        return list(conn.iterdump())
    finally:
        conn.close()


def digests() -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(RELEASE_0_1_0.iterdir())}


@pytest.fixture(scope="module", autouse=True)
def release_files_stay_untouched():
    before = digests()
    yield
    assert digests() == before, "a test wrote to the committed release-0.1.0 databases"


def job(i: int, state: str = "queued", updated_s: float | None = None) -> s.JobRecord:
    return s.JobRecord(job_id=f"job-{i:03d}", filename=f"part{i}.stl", state=state, created_s=1000.0 + i,
                       updated_s=1000.5 + i if updated_s is None else updated_s)


# --- (a) the previous release's databases -----------------------------------------------------

def test_release_0_1_0_jobs_migrate_to_columns_and_keep_every_record(tmp_path):
    path = release_copy(tmp_path, "jobs.sqlite")
    with sqlite3.connect(path) as conn:                  # what release 0.1.0 wrote, decoded the old way
        old = {jid: codec.decode(blob, s.JobRecord) for jid, blob in conn.execute("SELECT job_id, record FROM jobs")}
    conn.close()
    store = JobStore(path)
    try:
        assert store.db.versions() == {"jobs": 2, "follow": 1, "plate": 1}
        records = store.all()
        assert [r.job_id for r in records] == QUEUE_0_1_0                   # the queue order survives
        assert {r.job_id: r for r in records} == old                        # and every record, field by field
        assert store.last_event_seq() == 1234 and store.plate_clear() is False
        with store.db.read() as conn:
            cols = [r[1] for r in conn.execute("PRAGMA table_info(jobs)")]
            rows = conn.execute("SELECT job_id, state, filename, created_s, updated_s, started_s, ended_s "
                                "FROM jobs").fetchall()
            indexes = {r[1] for r in conn.execute("PRAGMA index_list(jobs)")}
        assert cols == ["job_id", "position", "state", "filename", "created_s", "updated_s", "started_s",
                        "ended_s", "record"]
        assert {r[0]: r[1:] for r in rows} == {j: (r.state, r.filename, r.created_s, r.updated_s, r.started_s,
                                                   r.ended_s) for j, r in old.items()}
        assert {"jobs_state_position", "jobs_updated"} <= indexes
        assert [r.job_id for r in store.in_states(["queued"])] == ["000000000004", "000000000003"]
        assert store.latest().job_id == "000000000004"
    finally:
        store.close()
    migrated = dump(path)
    JobStore(path).close()                                                   # opening again changes nothing
    assert dump(path) == migrated


def test_release_0_1_0_station_and_records_get_their_version_rows(tmp_path):
    path = release_copy(tmp_path, "station.sqlite")
    before = dump(path)
    store = StationStore(path)
    try:
        assert store.db.versions() == {"events": 1, "clock": 1, "checkpoint": 1, "beads": 1}
        events = store.events()
        assert [e.seq for e in events] == list(range(1, 11)) and store.last_seq() == 10
        assert events[4].kind == "note" and events[4].data == {"i": 5, "job_id": "000000000002"}
        ck = store.load()
        assert ck is not None and ck.t_mark_s == 10.0 and ck.state == {"meta": {"program_id": ""}, "twin": {"x": 1}}
        assert ck.beads["p0"].shape == (3, 3) and ck.beads["w"].tolist() == [1.0, 1.0, 1.0]
    finally:
        store.close()
    after = dump(path)
    assert [ln for ln in after if "schema_versions" not in ln] == before      # only the version rows were added
    StationStore(path).close()
    assert dump(path) == after

    path = release_copy(tmp_path, "records.sqlite")
    records = RecordStore(path)
    try:
        assert records.db.versions() == {"records": 1}
        assert records.get("slice", "abc", s.Ack) == s.Ack(ok=True, message="kept")
    finally:
        records.close()


# --- (b) a newer file, (c) a damaged one ----------------------------------------------------------

def test_a_table_newer_than_this_release_is_refused_naming_file_and_table(tmp_path):
    path = tmp_path / "jobs.sqlite"
    JobStore(path).close()
    with sqlite3.connect(path) as conn:
        conn.execute("UPDATE schema_versions SET version = 3 WHERE name = 'jobs'")
    conn.close()
    with pytest.raises(StoreError) as err:
        JobStore(path)
    assert err.value.code == "store"
    assert err.value.details == {"file": str(path), "table": "jobs", "version": 3, "supported": 2,
                                 "reason": "newer"}
    assert str(path) in err.value.message and "table jobs" in err.value.message
    with sqlite3.connect(path) as conn:                                      # and left as it was
        assert conn.execute("SELECT version FROM schema_versions WHERE name = 'jobs'").fetchone() == (3,)
    conn.close()


@pytest.mark.parametrize("store_type,name", [(JobStore, "jobs.sqlite"), (StationStore, "station.sqlite"),
                                             (RecordStore, "records.sqlite")])
@pytest.mark.parametrize("damage", ["truncated", "garbage"])
def test_a_damaged_file_is_a_typed_error_naming_it(tmp_path, store_type, name, damage):
    path = release_copy(tmp_path, name)
    if damage == "truncated":
        with open(path, "r+b") as fh:
            fh.truncate(path.stat().st_size // 2)
    else:
        path.write_bytes(b"\x00garbage, not SQLite" * 1000)
    with pytest.raises(StoreError) as err:
        store_type(path)
    assert {k: err.value.details[k] for k in ("file", "reason")} == {"file": str(path), "reason": "damaged"}
    assert err.value.details["problem"]                              # what SQLite or quick_check found
    assert str(path) in err.value.message and "damaged" in err.value.message and "move it aside" in err.value.message


def test_a_migration_that_cannot_read_a_record_leaves_the_file_as_it_was(tmp_path):
    path = release_copy(tmp_path, "jobs.sqlite")
    with sqlite3.connect(path) as conn:
        conn.execute("UPDATE jobs SET record = ? WHERE job_id = '000000000001'", (b"\xc1 not msgpack",))
    conn.close()
    before = dump(path)
    with pytest.raises(StoreError) as err:
        JobStore(path)
    assert err.value.details["reason"] == "migration" and err.value.details["table"] == "jobs"
    assert dump(path) == before                                              # rolled back: still release 0.1.0


# --- (d) every access serialised ----------------------------------------------------------------

def test_readers_never_see_a_half_done_transaction(tmp_path):
    """A writer saves all records with one stamp per transaction and rotates the queue (a move rewrites
    several positions); readers must only ever see one stamp and a rotation of the original order."""
    store = JobStore(tmp_path / "jobs.sqlite")
    records = [job(i) for i in range(6)]
    ids = [r.job_id for r in records]
    for rec in records:
        store.add(rec)
    rotations = {tuple(ids[k:] + ids[:k]) for k in range(len(ids))}
    stop = threading.Event()
    seen: list[str] = []
    reads = [0, 0, 0]
    rounds = [0]

    def write() -> None:
        order = list(ids)
        while not stop.is_set():
            rounds[0] += 1
            for rec in records:
                rec.stage = f"round {rounds[0]}"
            store.save(*records, last_event_seq=rounds[0])
            store.move(order[-1], 0, order)
            order = order[-1:] + order[:-1]

    def read(k: int) -> None:
        while not stop.is_set():
            page, total = store.page(0, 100) if k % 2 else (store.all(), len(ids))
            stages = {r.stage for r in page}
            order = tuple(r.job_id for r in page)
            if len(stages) != 1 or order not in rotations or total != len(ids):
                seen.append(f"stages {sorted(stages)}, order {order}, total {total}")
            reads[k] += 1

    threads = [threading.Thread(target=write)] + [threading.Thread(target=read, args=(k,)) for k in range(3)]
    for t in threads:
        t.start()
    stop.wait(2.0)                                   # a bounded run: no event ends it earlier
    stop.set()
    for t in threads:
        t.join(timeout=10)
    store.close()
    assert not any(t.is_alive() for t in threads)
    assert rounds[0] > 10 and min(reads) > 10, (rounds, reads)
    assert seen == []


def test_a_write_that_raises_is_rolled_back_whole(tmp_path):
    store = JobStore(tmp_path / "jobs.sqlite")
    a, b = job(1), job(2)
    store.add(a)
    a.state, b.state = "failed", "failed"
    with pytest.raises(Exception, match="no job job-002"):
        store.save(a, b, last_event_seq=7)           # b is unknown: a's change and the seq go too
    assert store.get("job-001").state == "queued" and store.last_event_seq() == 0
    store.close()


# --- (e) pages and queries -------------------------------------------------------------------

def test_page_in_states_latest_and_count(tmp_path):
    store = JobStore(tmp_path / "jobs.sqlite")
    assert store.page() == ([], 0) and store.latest() is None and store.count() == 0
    states = ["finished", "failed", "queued", "printing", "queued", "finished", "queued"]
    for i, st in enumerate(states):
        store.add(job(i, st, updated_s=2000.0 - i))           # job-000 changed last
    ids = [f"job-{i:03d}" for i in range(len(states))]

    def page_ids(*args, **kw) -> tuple[list[str], int]:
        recs, total = store.page(*args, **kw)
        return [r.job_id for r in recs], total

    assert page_ids(0, 3) == (ids[:3], 7)
    assert page_ids(5, 10) == (ids[5:], 7)
    assert page_ids(10, 5) == ([], 7) and page_ids(0, 0) == ([], 7)
    assert page_ids(1, 2, states=["queued", "finished"]) == (["job-002", "job-004"], 5)
    assert [r.job_id for r in store.in_states(["queued"])] == ["job-002", "job-004", "job-006"]
    assert store.in_states([]) == []
    assert store.count() == 7 and store.count(["queued"]) == 3
    assert store.latest().job_id == "job-000"

    store.move("job-006", 0, ["job-002", "job-004", "job-006"])                  # queue order is position
    assert [r.job_id for r in store.in_states(["queued"])] == ["job-006", "job-002", "job-004"]
    assert page_ids(0, 3, states=["queued"])[0] == ["job-006", "job-002", "job-004"]
    rec = store.get("job-004")
    rec.state, rec.updated_s = "slicing", 3000.0                                # columns follow the record
    store.save(rec)
    assert store.count(["queued"]) == 2 and store.latest().job_id == "job-004"
    assert [r.job_id for r in store.in_states(["slicing"])] == ["job-004"]
    store.remove("job-004")
    assert store.count() == 6 and store.latest().job_id == "job-000"

    with pytest.raises(ValidationError) as err:
        store.page(0, 10, states=["done"])
    assert err.value.details["field"] == "states"
    with pytest.raises(ValidationError):
        store.page(-1, 10)
    store.close()


def test_an_old_clients_empty_request_is_the_first_page():
    q = codec.decode(codec.encode(s.Empty()), s.JobsQuery)
    assert (q.offset, q.limit, q.states) == (0, 100, [])
    with pytest.raises(DecodeError):                       # only a bare Empty, and only for all-default types
        codec.decode(codec.pack({"_t": "common.Empty", "_v": 1, "limit": 5}), s.JobsQuery)
    with pytest.raises(DecodeError):
        codec.decode(codec.encode(s.Empty()), s.JobQuery)
    with pytest.raises(ValidationError) as err:
        codec.decode(codec.encode(s.JobsQuery(limit=s.MAX_JOBS_PAGE + 1)), s.JobsQuery)
    assert err.value.details["field"] == "limit"


def test_job_list_text_says_which_part_is_shown():
    recs = [job(i) for i in range(3)]
    assert "showing 2-4 of 9" in _list_text(s.JobList(jobs=recs, total=9, offset=1))
    assert "showing" not in _list_text(s.JobList(jobs=recs, total=3))
    assert "showing" not in _list_text(s.JobList(jobs=recs))                # -1: every job (job_move)
    assert _list_text(s.JobList(jobs=[], total=0)) == "no jobs"


# --- (f) over the wire --------------------------------------------------------------------------

def test_jobs_are_paged_over_the_wire(hub, session, settings, tmp_path):
    data_dir = tmp_path / "supervisor"
    store = JobStore(data_dir / "jobs.sqlite")
    for i, st in enumerate(["finished", "failed", "finished", "stopped", "finished"]):
        store.add(job(i, st))
    store.close()
    svc = SupervisorService(session, settings.cell, data_dir)
    svc.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("supervisor",), deadline_s=10)
            page = client.jobs(offset=1, limit=2)
            assert [r.job_id for r in page.jobs] == ["job-001", "job-002"] and (page.total, page.offset) == (5, 1)
            page = client.jobs(states=["finished"], limit=2)
            assert [r.job_id for r in page.jobs] == ["job-000", "job-002"] and page.total == 3
            old = client.call_raw("supervisor", "jobs", codec.encode(s.Empty()), s.JobList, 5.0)   # a v0.1 client
            assert [r.job_id for r in old.jobs] == [f"job-{i:03d}" for i in range(5)] and old.total == 5
            with pytest.raises(ValidationError) as err:
                client.jobs(limit=s.MAX_JOBS_PAGE + 1)
            assert err.value.details["field"] == "limit"
    finally:
        svc.close()
