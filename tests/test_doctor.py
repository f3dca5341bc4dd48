"""Damaged stores: a service stops in one line (exit 78), the launcher says so once and keeps the rest of the
cell running, ``fabric-cli doctor`` sets the file aside and recovers what can still be read."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
import uuid
from dataclasses import replace
from pathlib import Path

import pytest

from fabric import schemas as s
from fabric.cli.doctor import check_cell
from fabric.client import Client
from fabric.server.service import lock_dir
from fabric.services.host import EXIT_NO_RESTART, EXIT_NOTE_ENV
from fabric.store.jobs import JobStore
from fabric.wire.config import SessionSettings
from fabric.wire.keys import SERVICES

from support.loopback import free_port
from support.proc_lines import ProcLines

pytestmark = pytest.mark.timeout(240)

GARBAGE = b"\x00not SQLite at all, written over the file " * 500


def _cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fabric.cli.main", *args], capture_output=True, text=True,
                          timeout=timeout)


def _jobs(path: Path, n: int) -> list[s.JobRecord]:
    store = JobStore(path)
    recs = [s.JobRecord(job_id=f"job-{i:04d}", filename=f"part{i}.stl", reason="r" * 200, created_s=1000.0 + i)
            for i in range(n)]
    for rec in recs:
        store.add(rec)
    store.set_plate_clear(False)
    store.save(last_event_seq=77)
    store.close()
    return recs


def _up(cell: str, listen: str, data: Path, logs: Path) -> tuple[subprocess.Popen, ProcLines]:
    proc = subprocess.Popen([sys.executable, "-m", "fabric.cli.main", "up", "--cell", cell, "--listen", listen,
                             "--data-dir", str(data), "--log-dir", str(logs)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    return proc, ProcLines(proc)


def _end(proc: subprocess.Popen) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()


# --- the whole story, as an operator meets it ----------------------------------------------------------

def test_a_damaged_jobs_file_stops_the_supervisor_in_one_line_and_doctor_brings_the_cell_back(tmp_path):
    cell, data, logs = f"d{uuid.uuid4().hex[:8]}", tmp_path / "data", tmp_path / "logs"
    jobs = data / cell / "supervisor" / "jobs.sqlite"
    jobs.parent.mkdir(parents=True)
    jobs.write_bytes(GARBAGE)
    listen = f"tcp/127.0.0.1:{free_port()}"
    client_settings = SessionSettings(connect=[listen], cell=cell, mode="client")

    proc, out = _up(cell, listen, data, logs)
    try:
        held = out.wait(r"service supervisor stopped", 90)
        assert held is not None, out.text
        assert str(jobs) in held and f"fabric-cli doctor --cell {cell} --data-dir {data}" in held, held
        assert "not restarted" in held and "the rest of the cell keeps running" in held
        up = out.wait(rf"cell '{cell}' up", 90)
        assert up is not None and "not running: supervisor" in up, out.text
        assert out.wait(r"Ctrl-C stops", 10) is not None
        others = tuple(n for n in SERVICES if n != "supervisor")
        with Client.connect(client_settings) as client:
            client.wait_alive(others, deadline_s=30)
            # no restart loop: the first restart would come 0.5 s after the exit; none in six times that
            assert out.wait(r"supervisor (restarted|exited)", 3.0) is None, out.text
            assert not client.alive(timeout=1.0)["supervisor"]
        log = (logs / "supervisor.log").read_text()
        assert log.count("cannot start") == 1 and "Traceback" not in log, log
        assert re.search(rf"supervisor cannot start: {re.escape(str(jobs))} is damaged \(file is not a database\); "
                         r"a restart cannot fix this: run 'fabric-cli doctor", log), log

        # the doctor, while the rest of the cell runs: the file is set aside (kept) and a fresh one made ...
        doc = _cli("doctor", "--cell", cell, "--data-dir", str(data))
        assert doc.returncode == 0, doc.stdout + doc.stderr
        line = next(ln for ln in doc.stdout.splitlines() if "jobs.sqlite" in ln)
        assert "damaged (file is not a database): moved aside as jobs.sqlite.damaged-" in line, doc.stdout
        assert "the supervisor starts with an empty store" in line
        kept = [p for p in jobs.parent.iterdir() if p.name.startswith("jobs.sqlite.damaged-")]
        assert len(kept) == 1 and kept[0].read_bytes() == GARBAGE
        # ... and the running launcher starts the supervisor again by itself
        assert out.wait(r"service supervisor: .* has changed .*started it again", 30) is not None, out.text
        with Client.connect(client_settings) as client:
            client.wait_alive(SERVICES, deadline_s=60)
            assert client.jobs().total == 0
    finally:
        assert _end(proc) == 1                      # a service stopped during the run: said in the exit code

    # the next start: the whole cell comes up, nothing to say
    proc, out = _up(cell, listen, data, logs)
    try:
        up = out.wait(rf"cell '{cell}' up", 120)
        assert up is not None and "not running" not in up, out.text
        with Client.connect(client_settings) as client:
            client.wait_alive(SERVICES, deadline_s=30)
    finally:
        assert _end(proc) == 0, out.text
    assert "!!" not in out.text, out.text


def test_the_service_exits_78_with_one_line_and_leaves_the_launcher_a_note(tmp_path):
    cell, data = f"d{uuid.uuid4().hex[:8]}", tmp_path / "data"
    jobs = data / cell / "supervisor" / "jobs.sqlite"
    jobs.parent.mkdir(parents=True)
    jobs.write_bytes(GARBAGE)
    note = tmp_path / "note.json"
    t0 = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "fabric.cli.main", "serve", "supervisor", "--cell", cell,
                           "--connect", f"tcp/127.0.0.1:{free_port()}", "--data-dir", str(data)],
                          capture_output=True, text=True, timeout=60,
                          env=dict(os.environ, **{EXIT_NOTE_ENV: str(note)}))
    assert done.returncode == EXIT_NO_RESTART, done.stdout + done.stderr
    lines = [ln for ln in (done.stdout + done.stderr).splitlines() if ln.strip()]
    assert len(lines) == 1, lines                               # one line, no traceback
    assert str(jobs) in lines[0] and f"fabric-cli doctor --cell {cell} --data-dir {data}" in lines[0]
    got = json.loads(note.read_text())
    assert {k: got[k] for k in ("service", "code", "file", "reason")} == {
        "service": "supervisor", "code": 78, "file": str(jobs), "reason": "damaged"}
    assert time.monotonic() - t0 < 30


# --- the doctor on its own -------------------------------------------------------------------------

def test_doctor_recovers_the_readable_rows_of_a_truncated_file_and_keeps_the_original(tmp_path):
    cell = "c1"
    path = tmp_path / cell / "supervisor" / "jobs.sqlite"
    recs = _jobs(path, 400)
    with open(path, "r+b") as fh:                               # the end of the file is lost
        fh.truncate(path.stat().st_size // 2)
    damaged = path.read_bytes()

    check = _cli("doctor", "--cell", cell, "--data-dir", str(tmp_path), "--check")
    assert check.returncode == 1 and "damaged" in check.stdout and path.read_bytes() == damaged   # only says

    reports = check_cell(tmp_path, cell)
    (rep,) = [r for r in reports if r["name"] == "jobs.sqlite"]
    assert rep["status"] == "repaired" and "jobs" in rep["incomplete"], rep
    assert Path(rep["kept_as"]).read_bytes() == damaged and Path(rep["kept_as"]).parent == path.parent
    store = JobStore(path)                                      # the real store opens it: quick_check passes
    try:
        got = store.all()
        assert 0 < len(got) < len(recs), len(got)
        assert got == recs[:len(got)]                           # the rows before the damage, exactly
        assert store.last_event_seq() == 77 and store.plate_clear() is False    # the small tables too
    finally:
        store.close()
    assert _cli("doctor", "--cell", cell, "--data-dir", str(tmp_path)).returncode == 0   # sound now


def test_doctor_goes_past_a_damaged_page_and_reads_the_table_from_both_ends(tmp_path):
    path = tmp_path / "c1" / "supervisor" / "jobs.sqlite"
    recs = _jobs(path, 400)
    with open(path, "r+b") as fh:                               # three pages in the middle overwritten
        fh.seek(4096 * 20)
        fh.write(GARBAGE[:3 * 4096])
    (rep,) = [r for r in check_cell(tmp_path, "c1") if r["name"] == "jobs.sqlite"]
    assert rep["status"] == "repaired", rep
    store = JobStore(path)
    try:
        got = {r.job_id: r for r in store.all()}
    finally:
        store.close()
    assert len(recs) - 40 < len(got) < len(recs)                # all but the rows of the damaged pages
    assert all(got[j] == r for r in recs if (j := r.job_id) in got)
    assert recs[0].job_id in got and recs[-1].job_id in got     # from both ends


def test_doctor_on_garbage_starts_empty_and_leaves_a_running_services_files_alone(tmp_path):
    path = tmp_path / "c1" / "supervisor" / "jobs.sqlite"
    path.parent.mkdir(parents=True)
    path.write_bytes(GARBAGE)
    Path(f"{path}-wal").write_bytes(b"junk wal")
    holder = lock_dir(path.parent, "supervisor", "c1")        # as a running supervisor holds it
    try:
        (rep,) = check_cell(tmp_path, "c1")
        assert rep["status"] == "damaged" and "in_use" in rep and path.read_bytes() == GARBAGE
    finally:
        holder.close()
    done = _cli("doctor", "--cell", "c1", "--data-dir", str(tmp_path), "--json")
    assert done.returncode == 0, done.stdout + done.stderr
    (rep,) = json.loads(done.stdout)["files"]
    assert rep["status"] == "repaired" and rep["unreadable"]
    kept = Path(rep["kept_as"])
    assert kept.read_bytes() == GARBAGE and Path(f"{kept}-wal").read_bytes() == b"junk wal"
    assert not Path(f"{path}-wal").exists() or Path(f"{path}-wal").read_bytes() != b"junk wal"
    store = JobStore(path)
    assert store.count() == 0
    store.close()


def test_doctor_fixes_a_damaged_artifact_index_which_the_service_now_refuses_in_one_line(tmp_path):
    index = tmp_path / "c1" / "planner" / "artifacts" / "index.sqlite"
    index.parent.mkdir(parents=True)
    index.write_bytes(GARBAGE)
    from fabric.store.artifacts import ArtifactStore
    from fabric.wire.errors import StoreError
    with pytest.raises(StoreError) as err:                      # a typed error naming it, not a raw sqlite3 one
        ArtifactStore(index.parent)
    assert err.value.details["file"] == str(index) and err.value.details["reason"] == "damaged"
    (rep,) = check_cell(tmp_path, "c1")
    assert rep["status"] == "repaired"
    ArtifactStore(index.parent).close()


def test_a_running_launchers_settings_are_what_the_note_names(tmp_path):
    """The launcher builds its line from the note, not from parsing a log (unit: CellProcesses._hold)."""
    from fabric.cli.up import CellProcesses, _Child

    cell = CellProcesses(replace(SessionSettings(cell="c1"), connect=["tcp/127.0.0.1:1"]), data_dir=tmp_path)
    cell._notes = tmp_path
    (tmp_path / "supervisor.json").write_text(json.dumps(
        {"service": "supervisor", "code": 78, "file": str(tmp_path / "jobs.sqlite"), "reason": "damaged",
         "doctor": f"fabric-cli doctor --cell c1 --data-dir {tmp_path}"}))
    line = cell._hold(_Child("supervisor", proc=None, started_s=0.0))
    assert line.count("\n") == 0 and str(tmp_path / "jobs.sqlite") in line and "fabric-cli doctor --cell c1" in line
