"""The supervisor's file library (issue 24): every submitted file is kept with what its last job did, and
printed again from the library through the CLI; a refused submission or a bad file changes nothing; the
library survives a restart of the supervisor."""
from __future__ import annotations

import json
import time
from dataclasses import replace

import pytest
from test_job_record_shift import tower_gcode, wait_job

from fabric import schemas as s
from fabric.cli.main import main
from fabric.client import Client
from fabric.robot.cell import Cell
from fabric.services.collision import CollisionService
from fabric.services.planner import PlannerService
from fabric.services.station import StationService
from fabric.services.supervisor import SupervisorService
from fabric.store.library import LibraryStore, entry_id
from fabric.wire.errors import NotFound, ValidationError

pytestmark = pytest.mark.timeout(240)


def _entry(name: str, data: bytes, used_s: float) -> s.LibraryFile:
    cid = f"{abs(hash(data)):016x}"
    return s.LibraryFile(file_id=entry_id(cid, name), name=name, source="gcode", content_id=cid,
                         size_bytes=len(data), added_s=used_s, used_s=used_s)


def test_the_store_finds_by_prefix_pages_by_last_use_and_survives_reopening(tmp_path):
    store = LibraryStore(tmp_path / "library.sqlite")
    a, b = _entry("a.gcode", b"1", 100.0), _entry("b.gcode", b"2", 200.0)
    store.put(a)
    store.put(b)
    assert entry_id(a.content_id, a.name) == a.file_id != entry_id(a.content_id, "other.gcode")
    assert store.get(a.file_id[:6]).name == "a.gcode"
    with pytest.raises(ValidationError, match="too short"):
        store.get(a.file_id[:3])
    with pytest.raises(NotFound):
        store.get("ffffffffffff")
    files, total = store.page(0, 10)
    assert [f.name for f in files] == ["b.gcode", "a.gcode"] and total == 2
    assert [f.name for f in store.page(0, 10, "A.G")[0]] == ["a.gcode"]
    store.close()
    again = LibraryStore(tmp_path / "library.sqlite")
    assert again.get(b.file_id) == b
    again.remove(b.file_id)
    assert again.page(0, 10)[1] == 1
    again.close()


def _services(session, settings, tmp_path) -> list:
    cell = Cell.builtin("irb140")
    return [PlannerService(session, settings.cell, cell, data_dir=tmp_path / "planner"),
            CollisionService(session, settings.cell, cell),
            StationService(session, settings.cell, cell, data_dir=tmp_path / "station"),
            SupervisorService(session, settings.cell, data_dir=tmp_path / "supervisor")]


def _cli_json(capsys, *argv: str):
    rc = main(list(argv))
    out = capsys.readouterr()
    assert rc == 0, out.err
    return json.loads(out.out)


def test_submitted_files_are_kept_and_printed_again_from_the_library(session, settings, tmp_path, capsys):
    services = _services(session, settings, tmp_path)
    for svc in services:
        svc.start()
    args = replace(settings, mode="client").to_args()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station", "collision", "planner", "supervisor"), deadline_s=20)
            # a refused submission leaves no file behind
            with pytest.raises(ValidationError, match="not sliced"):
                client.submit(s.JobSubmit(model=tower_gcode(3), filename="tower.gcode", overrides={"a": "1"}))
            with pytest.raises(ValidationError, match="source"):
                client.file_add(b"G1 X1\n", "notes.txt")
            assert client.files().total == 0

            first = client.submit(s.JobSubmit(model=tower_gcode(3), filename="tower.gcode", start=True,
                                              rtf=0.0)).job_id
            done = wait_job(client, first, lambda r: r.state == "finished")
            (entry,) = client.files().files
            assert (entry.name, entry.source, entry.jobs, entry.last_job_id) == ("tower.gcode", "gcode", 1, first)
            assert entry.last_state == "finished" and entry.layers == done.plan.layers == 3
            assert entry.extruded_mm3 == pytest.approx(done.plan.extruded_mm3)
            assert entry.rtf == 0.0                                  # "print again" reuses the last settings

            # the same file again is the same entry; a file only kept is not printed
            kept = client.file_add(tower_gcode(5), "tall.gcode")
            assert client.file_add(tower_gcode(5), "tall.gcode").file_id == kept.file_id
            assert client.files().total == 2 and client.jobs().total == 1

            # fabric-cli: list, show by a prefix, print again (the plate holds the first part: job next)
            listed = _cli_json(capsys, "files", "list", "--json", *args)
            assert {f["name"] for f in listed["files"]} == {"tower.gcode", "tall.gcode"}
            shown = _cli_json(capsys, "files", "show", entry.file_id[:6], "--json", *args)
            assert shown["file_id"] == entry.file_id
            again = _cli_json(capsys, "files", "print", entry.file_id[:8], "--start", "--json", *args)["job_id"]
            waiting = wait_job(client, again, lambda r: r.prepared and r.waiting_for == "plate")
            assert (waiting.filename, waiting.rtf, waiting.model_id) == ("tower.gcode", 0.0, done.model_id)
            client.job_next()
            second = wait_job(client, again, lambda r: r.state == "finished")
            assert second.deposited_mm3 == pytest.approx(done.deposited_mm3)
            entry = client.file(entry.file_id)
            assert (entry.jobs, entry.last_job_id, entry.last_state) == (2, again, "finished")

            # the bytes come back as they were
            out = tmp_path / "back.gcode"
            assert main(["files", "get", entry.file_id, "-o", str(out), *args]) == 0
            assert out.read_bytes() == tower_gcode(3)

            # removed: gone from the list, and a job from it is refused (nothing queued)
            assert main(["files", "rm", kept.file_id, *args]) == 0
            capsys.readouterr()
            with pytest.raises(NotFound):
                client.submit(s.JobSubmit(model=b"", filename="", file_id=kept.file_id))
            assert client.files().total == 1 and client.jobs().total == 2
            with pytest.raises(ValidationError, match="not both"):
                client.submit(s.JobSubmit(model=tower_gcode(3), filename="x.gcode", file_id=entry.file_id))
    finally:
        for svc in reversed(services):
            svc.close()

    # the library is the supervisor's durable state: a new supervisor on the same folder has it
    sup = SupervisorService(session, settings.cell, data_dir=tmp_path / "supervisor")
    sup.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("supervisor",), deadline_s=20)
            deadline = time.monotonic() + 10
            while client.files().total != 1:
                assert time.monotonic() < deadline
                time.sleep(0.05)
            assert client.file(entry.file_id).jobs == 2
    finally:
        sup.close()


def _far_tower() -> bytes:
    """A tower far out of the robot's reach: planned, every target unreachable, no time estimate (-1)."""
    return tower_gcode(2).replace(b"X100", b"X2100").replace(b"X130", b"X2130")


def test_a_file_whose_job_was_unreachable_can_be_listed_and_submitted_again(session, settings, tmp_path):
    """Found driving the cell: a job refused as unreachable left its file's entry with the planner's -1 s
    estimate, which the entry's schema refuses, and the next submission of the file failed with "field
    'estimate_s': -1.0 is below the minimum 0.0"."""
    services = _services(session, settings, tmp_path)
    for svc in services:
        svc.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station", "collision", "planner", "supervisor"), deadline_s=20)
            for _ in range(2):
                job = client.submit(s.JobSubmit(model=_far_tower(), filename="far.gcode"))
                failed = wait_job(client, job.job_id, lambda r: r.state == "failed")
                assert failed.reason.startswith("unreachable") and failed.plan.estimate_s < 0
                (entry,) = client.files().files
                assert (entry.last_state, entry.estimate_s) == ("failed", 0.0)
            assert client.file(entry.file_id).jobs == 2
    finally:
        for svc in reversed(services):
            svc.close()


def test_an_entry_stored_with_a_negative_estimate_reads_as_no_estimate(tmp_path):
    """Entries a library before this fix wrote are read, not refused."""
    from fabric.wire import codec
    store = LibraryStore(tmp_path / "library.sqlite")
    entry = _entry("far.gcode", b"3", 100.0)
    store.put(entry)
    body = codec.unpack(codec.encode(entry))
    body["estimate_s"] = -1.0
    with store.db.write() as conn:
        conn.execute("UPDATE library SET entry = ? WHERE file_id = ?", (codec.pack(body), entry.file_id))
    assert store.get(entry.file_id).estimate_s == 0.0
    assert store.page(0, 10)[0][0].estimate_s == 0.0
    store.close()
