"""The protocol documents say what the services do (issue 37, point 9): each rule a client written from
docs/protocol.md alone relies on, checked against the code, and over real Zenoh where a service applies it.

A newer ``_v`` is refused for every type, ``common.Empty`` included; a ``validation`` error always names its
``schema``; an empty payload's ``decode`` error carries the documented details; the id rules are in the JSON
Schema; a job is submitted from an upload, and the inline limits are stated; artifact queries are in the
endpoint table with their timeout; paging says what ``last_seq`` and an empty page are; the document names
no code constant for a definition, and writes sizes in MiB only."""
from __future__ import annotations

import ast
import hashlib
import json
import re
from dataclasses import replace
from pathlib import Path

import jsonschema
import msgpack
import pytest
import zenoh

import fabric.cli.inputs
import fabric.client.client
from fabric import schemas as s
from fabric.cli.main import main
from fabric.client import Client
from fabric.printjobs.library import check_size
from fabric.protocol_doc import render
from fabric.reference.errors import ERROR_DETAILS
from fabric.reference.fields import member_docs
from fabric.robot.cell import Cell
from fabric.schemas import REGISTRY, states
from fabric.schemas.upload import MAX_GCODE_BYTES, MAX_MODEL_BYTES, UPLOAD_CHUNK_MAX_BYTES
from fabric.services.station import StationService
from fabric.services.supervisor import SupervisorService
from fabric.wire import codec
from fabric.wire.errors import DecodeError, NotFound, ValidationError
from fabric.wire.keys import ARTIFACT_SOURCES, ARTIFACT_TIMEOUT_S, ENDPOINTS

pytestmark = pytest.mark.timeout(180)

ROOT = Path(__file__).resolve().parents[1]
GCODE = ("G21\nG90\nM83\nG1 Z0.4 F1200\n" + "".join(f"G1 X{100 + k % 20} Y{100 + k // 20} E0.1 F1500\n"
                                                     for k in range(400))).encode()


@pytest.fixture(scope="module")
def doc() -> dict:
    return json.loads((ROOT / "docs" / "protocol.json").read_text())


@pytest.fixture(scope="module")
def md() -> str:
    return render()


def _def(doc: dict, type_name: str, field: str) -> dict:
    return doc["$defs"][type_name]["properties"][field]


def _valid(doc: dict, type_name: str, value: dict) -> bool:
    root = {"$defs": doc["$defs"], "$ref": f"#/$defs/{type_name}"}
    return jsonschema.Draft202012Validator(root).is_valid(value)


# --- 1. a newer version is refused, for every type ------------------------------------------------------------

@pytest.mark.parametrize("name", sorted(REGISTRY))
def test_a_newer_version_is_refused_for_every_type(name: str) -> None:
    cls = REGISTRY[name]
    with pytest.raises(DecodeError) as err:
        codec.decode(codec.pack({"_t": name, "_v": cls.VERSION + 1}), cls)
    assert err.value.details == {"reason": "version", "got": cls.VERSION + 1, "supported": cls.VERSION,
                                 "expected": name}


def test_an_empty_message_of_a_newer_version_is_refused_where_it_stands_for_a_request() -> None:
    """It was taken for an all-default request whatever its ``_v`` (``{"_t": "common.Empty", "_v": 99}`` asked
    the first page of supervisor/jobs)."""
    assert codec.decode(codec.encode(s.Empty()), s.JobsQuery) == s.JobsQuery()
    for version in (99, 0, "1", None):
        with pytest.raises(DecodeError) as err:
            codec.decode(codec.pack({"_t": "common.Empty", "_v": version}), s.JobsQuery)
        assert err.value.details["reason"] == "version" and err.value.details["got"] == version
        assert err.value.details["supported"] == s.Empty.VERSION


# --- 2. a validation error names its schema -------------------------------------------------------------------

def test_a_validation_error_names_the_field_and_the_message_type_it_is_in() -> None:
    """A field's error carried only ``field`` (the schema only for a missing or unknown field)."""
    with pytest.raises(ValidationError) as err:
        codec.decode(codec.pack({"_t": "station.Overrides", "_v": 1, "speed_r": "fast"}), s.Overrides)
    assert err.value.details == {"field": "speed_r", "schema": "station.Overrides"}
    record = codec.unpack(codec.encode(s.FabricStatus(cell="c", services=[], job=s.JobRecord(job_id="j",
                                                                                          filename="f.gcode"))))
    record["job"]["progress_r"] = 2.0                                 # nested: the path from the top message
    with pytest.raises(ValidationError) as err:
        codec.decode(codec.pack(record), s.FabricStatus)
    assert err.value.details == {"field": "job.progress_r", "schema": "supervisor.Status"}
    record["job"]["bogus"] = 1
    with pytest.raises(ValidationError) as err:
        codec.decode(codec.pack(record), s.FabricStatus)
    assert err.value.details == {"field": "job.bogus", "schema": "supervisor.Status"}
    assert "`schema`" in ERROR_DETAILS["validation"] and "always" in ERROR_DETAILS["validation"]


# --- 3. an empty payload's decode error -----------------------------------------------------------------------

def test_an_empty_payload_is_a_decode_error_with_the_documented_details(md: str) -> None:
    """It said only ``reason`` "ValueError"; the document listed ``got``/``expected`` and ``got``/``supported``."""
    with pytest.raises(DecodeError) as err:
        codec.decode(b"", s.JobQuery)
    assert err.value.details == {"reason": "empty", "expected": "common.JobQuery"}
    documented = set(re.findall(r"`(\w+)` \(", ERROR_DETAILS["decode"]))
    for payload, reason in ((b"\xc1", "msgpack"), (msgpack.packb([1]), "not_map"),
                            (codec.encode(s.Empty()), "type")):
        with pytest.raises(DecodeError) as err:
            codec.decode(payload, s.JobQuery)
        assert err.value.details["reason"] == reason and set(err.value.details) <= documented | {"got"}
    assert reason in codec.DECODE_REASONS
    assert "`details.reason` `empty` and `details.expected`" in md


# --- 4. the id rules are in the JSON Schema -------------------------------------------------------------------

def test_the_id_rules_of_the_prose_are_in_the_json_schema(doc: dict) -> None:
    """An upload id's characters and a file id's shortest start were said in words only."""
    chunk = {"upload_id": "../etc/passwd", "offset": 0, "total_bytes": 1}
    assert not _valid(doc, "upload.Chunk", chunk)
    assert _valid(doc, "upload.Chunk", {**chunk, "upload_id": "a41f0c9e2b7d4e18"})
    for type_name in ("planner.PlanRequest", "slicer.SliceRequest", "supervisor.JobSubmit"):
        assert _def(doc, type_name, "upload_id")["pattern"] == "^(?:(?:[A-Za-z0-9_-]{8,64})?)$"
    submit = {"model": "", "filename": ""}
    assert _valid(doc, "supervisor.JobSubmit", {**submit, "file_id": "0d4be9"})
    assert not _valid(doc, "supervisor.JobSubmit", {**submit, "file_id": "0d4"})
    assert not _valid(doc, "supervisor.JobSubmit", {**submit, "upload_id": "short"})
    assert _def(doc, "supervisor.FileQuery", "file_id")["minLength"] == 6
    assert not _valid(doc, "supervisor.FileQuery", {"file_id": "0d4be"})
    # and the decoders apply them, naming the field and the message
    with pytest.raises(ValidationError) as err:
        codec.decode(codec.encode(s.UploadChunk(upload_id="../etc", offset=0, total_bytes=1)), s.UploadChunk)
    assert err.value.details == {"field": "upload_id", "schema": "upload.Chunk"}
    with pytest.raises(ValidationError) as err:
        codec.decode(codec.encode(s.FileQuery(file_id="0d4")), s.FileQuery)
    assert err.value.details == {"field": "file_id", "schema": "supervisor.FileQuery"}


# --- 5. inline sizes are stated and held --------------------------------------------------------------------

def test_inline_sizes_are_stated_in_mib_and_held(doc: dict, md: str) -> None:
    """"Inline inputs up to 4 MB are usual" said nothing of what a service takes; nothing refused more."""
    assert _def(doc, "planner.PlanRequest", "gcode")["x-max-bytes"] == MAX_GCODE_BYTES
    assert _def(doc, "slicer.SliceRequest", "model")["x-max-bytes"] == MAX_MODEL_BYTES
    assert _def(doc, "upload.Chunk", "data")["x-max-bytes"] == UPLOAD_CHUNK_MAX_BYTES
    rows = {(i["command"], i["field"], i["upload"], i["max_bytes"]) for i in doc["inputs"]}
    assert ("supervisor/submit", "model", "supervisor/upload", MAX_GCODE_BYTES) in rows
    assert ("planner/plan", "gcode", "planner/upload", MAX_GCODE_BYTES) in rows
    assert ("slicer/slice", "model", "slicer/upload", MAX_MODEL_BYTES) in rows
    assert "| `gcode` | `planner/upload` | 512 MiB |" in md and "up to 256 MiB" in md
    big = s.UploadChunk(upload_id="big-piece", offset=0, total_bytes=10 << 20, data=b"x" * (UPLOAD_CHUNK_MAX_BYTES + 1))
    with pytest.raises(ValidationError) as err:
        codec.decode(codec.encode(big), s.UploadChunk)
    assert err.value.details == {"field": "data", "schema": "upload.Chunk"}
    with pytest.raises(ValidationError) as err:                 # a model the slicer would refuse after queueing
        check_size(MAX_MODEL_BYTES + 1, "model", "model")
    assert err.value.details["field"] == "model" and "256 MiB" in err.value.message
    check_size(MAX_MODEL_BYTES + 1, "gcode", "model")


# --- 6. artifact queries in the endpoint table ---------------------------------------------------------------

def test_artifact_queries_are_in_the_endpoint_table_with_their_timeout(doc: dict, md: str,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    for svc, src in ARTIFACT_SOURCES.items():
        assert re.search(rf"^\| `am/<cell>/{svc}/artifact/<id>` \| no payload \| \[`common.Artifact`\].* \| "
                         rf"{src.timeout_s:g} s \| DATA, bulk \|", md, re.M), svc
    assert {q["service"]: q["timeout_s"] for q in doc["artifact_queries"]} == {
        svc: ARTIFACT_TIMEOUT_S for svc in ARTIFACT_SOURCES}
    asked: list[float] = []                     # and the client waits that long

    def get_one(self, key, payload, reply_type, timeout, what, *args, **kw):
        asked.append(timeout)
    monkeypatch.setattr(Client, "_get_one", get_one)
    Client(None, "cell1").artifact("planner", "0" * 64)       # type: ignore[arg-type]
    assert asked == [ARTIFACT_TIMEOUT_S]


# --- 8. states and sizes, not code names ---------------------------------------------------------------------

def test_the_document_lists_the_states_and_writes_sizes_in_mib_only(md: str) -> None:
    """JobRecord said "(see PRINT_JOB_STATES)" and upload.Chunk "at most 8 MB (``UPLOAD_CHUNK_MAX_BYTES``)"; "MB"
    meant 2^20 bytes without saying so."""
    names = set(re.findall(r"\b[A-Z][A-Z0-9]*_[A-Z0-9_]+\b", md))
    assert names <= {"FABRIC_CELL", "FABRIC_HUB", "FABRIC_LEASE_MS", "FABRIC_MAX_INPUT_MB", "INTERACTIVE_HIGH",
                     "BEST_MATCHING", "LAYER_CHANGE"}, names
    assert not re.search(r"\d ?MB\b", md) and "1 MiB = 2^20 = 1,048,576" in md
    for heading, enum in (("### Print job states", states.PrintJob), ("`common.JobStatus.state`:", states.Job)):
        section = md.split(heading, 1)[1]
        table = section[section.index("| state | meaning |"):].split("\n\n", 1)[0]
        for value, meaning in member_docs(enum).items():
            assert meaning and f"| `{value}` | {meaning} |" in table, value


# --- point 4: the reference asks other modules for public names ----------------------------------------------

def test_the_protocol_doc_reads_no_private_name_of_another_module() -> None:
    tree = ast.parse((ROOT / "fabric" / "protocol_doc.py").read_text())
    private = [f"import {a.name}" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)
               for a in n.names if a.name.startswith("_")]
    private += [f".{n.attr}" for n in ast.walk(tree) if isinstance(n, ast.Attribute)
                and n.attr.startswith("_") and not n.attr.startswith("__")]
    assert not private, private


# --- over Zenoh: the supervisor --------------------------------------------------------------------------------

@pytest.fixture
def supervisor(session, settings, tmp_path):
    svc = SupervisorService(session, settings.cell, data_dir=tmp_path / "supervisor")
    svc.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("supervisor",), deadline_s=20)
            yield client
    finally:
        svc.close()


def _error(client: Client, service: str, command: str, payload: bytes) -> s.ErrorReply:
    replies = list(client.session.get(client.keys.cmd(service, command), payload=payload,
                                      timeout=ENDPOINTS[(service, command)].timeout_s,
                                      consolidation=zenoh.ConsolidationMode.NONE))
    assert len(replies) == 1 and replies[0].err is not None
    return codec.decode(replies[0].err.payload.to_bytes(), s.ErrorReply)


def test_a_job_is_submitted_from_an_upload(supervisor: Client, tmp_path: Path) -> None:
    """JobSubmit carried the file inline only, so a large one was held whole by client, hub and supervisor."""
    client = supervisor
    path = tmp_path / "part.gcode"
    path.write_bytes(GCODE)
    uid = client.upload("supervisor", path, MAX_GCODE_BYTES, chunk_bytes=1024)
    acc = client.submit(s.JobSubmit(model=b"", filename="part.gcode", upload_id=uid))
    rec = client.job(acc.job_id)
    assert (rec.filename, rec.source, rec.model_id) == ("part.gcode", "gcode", hashlib.sha256(GCODE).hexdigest())
    assert client.artifact("supervisor", rec.model_id).data == GCODE
    (entry,) = client.files().files
    assert (entry.name, entry.size_bytes, entry.last_job_id) == ("part.gcode", len(GCODE), acc.job_id)
    with pytest.raises(NotFound) as err:                          # an upload serves one request
        client.submit(s.JobSubmit(model=b"", filename="part.gcode", upload_id=uid))
    assert err.value.details["upload_id"] == uid
    uid = client.upload("supervisor", path, MAX_GCODE_BYTES)
    with pytest.raises(ValidationError, match="not both") as err:
        client.submit(s.JobSubmit(model=GCODE, filename="part.gcode", upload_id=uid))
    assert err.value.details == {"field": "upload_id", "schema": "supervisor.JobSubmit"}
    assert client.jobs().total == 1


def test_job_submit_uploads_a_large_file(supervisor: Client, settings, tmp_path: Path, capsys,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """``fabric-cli job submit`` read the whole file into the request, whatever its size."""
    monkeypatch.setattr(fabric.cli.inputs, "INLINE_MAX_BYTES", 1000)      # GCODE is larger: it goes by upload
    uploads: list[str] = []
    upload_file = fabric.client.client.upload_file

    def spy(client, service, *args, **kw):
        uploads.append(service)
        return upload_file(client, service, *args, **kw)
    monkeypatch.setattr(fabric.client.client, "upload_file", spy)
    path = tmp_path / "large.gcode"
    path.write_bytes(GCODE)
    assert main(["job", "submit", str(path), "--json", *replace(settings, mode="client").to_args()]) == 0
    job_id = json.loads(capsys.readouterr().out)["job_id"]
    assert uploads == ["supervisor"]
    rec = supervisor.job(job_id)
    assert supervisor.artifact("supervisor", rec.model_id).data == GCODE and rec.filename == "large.gcode"


def test_the_supervisor_answers_as_documented(supervisor: Client) -> None:
    client = supervisor
    err = _error(client, "supervisor", "status", b"")                              # 3. an empty payload
    assert (err.code, err.details) == ("decode", {"reason": "empty", "expected": "common.Empty"})
    err = _error(client, "supervisor", "jobs", codec.pack({"_t": "common.Empty", "_v": 99}))   # 1. a newer _v
    assert (err.code, err.details) == ("decode", {"reason": "version", "got": 99, "supported": 1,
                                                  "expected": "supervisor.JobsQuery"})
    err = _error(client, "supervisor", "file", codec.encode(s.FileQuery(file_id="0d4")))      # 4. the id rule
    assert (err.code, err.details["field"], err.details["schema"]) == ("validation", "file_id", "supervisor.FileQuery")
    # 2. a refusal by the service's own check of the request names the request's schema too
    with pytest.raises(ValidationError, match="cannot tell from the file name") as raised:
        client.submit(s.JobSubmit(model=GCODE, filename="notes.txt"))
    assert (raised.value.details["field"], raised.value.details["schema"]) == ("source", "supervisor.JobSubmit")
    # 7. a page past the end is empty, and says so
    client.submit(s.JobSubmit(model=GCODE, filename="one.gcode"))
    page = client.jobs(offset=5, limit=10)
    assert (page.jobs, page.total, page.offset) == ([], 1, 5)
    assert client.jobs(limit=0).jobs == [] and client.files(offset=3).files == []


# --- over Zenoh: the station's event pages ----------------------------------------------------------------------

def test_event_pages_include_last_seq_and_an_empty_page_says_where_to_go_on(session, settings, tmp_path,
                                                                            md: str) -> None:
    """The document said "page on with next_seq until last_seq" without saying whether last_seq is on a page, nor
    what a page with nothing in it holds."""
    station = StationService(session, settings.cell, Cell.builtin("irb140"), data_dir=tmp_path / "station")
    station.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station",), deadline_s=20)
            client.clear_plate()                                        # an event, at least
            last = client.events(limit=1).last_seq
            assert last >= 1
            page = client.events(since_seq=last)                        # inclusive: the newest is on a page
            assert page.events[0].seq == last and page.next_seq == page.events[-1].seq + 1 > page.last_seq
            empty = client.events(since_seq=page.last_seq + 1)
            assert (empty.events, empty.next_seq, empty.last_seq) == ([], page.last_seq + 1, page.last_seq)
            ahead = client.events(since_seq=page.last_seq + 10)
            assert (ahead.events, ahead.next_seq) == ([], page.last_seq + 10)
            none = client.events(since_seq=0, kinds=["finished"])         # none of these kinds
            assert (none.events, none.next_seq) == ([], none.last_seq + 1)
    finally:
        station.close()
    assert "itself **included**" in md and "An **empty page**" in md
