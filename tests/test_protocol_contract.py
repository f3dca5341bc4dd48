"""The protocol as a contract: the reference is current, complete and uncut, its JSON description is valid,
and real replies and publications of in-process services over real Zenoh validate against it."""
from __future__ import annotations

import hashlib
import json
import queue
import re
import time
from pathlib import Path

import jsonschema
import msgpack
import pytest
import zenoh

from fabric import schemas as s
from fabric.client import Client
from fabric.protocol_doc import LOSSLESS, description, render, render_json
from fabric.reference import examples
from fabric.reference.events import EVENTS
from fabric.reference.fields import _comments, field_docs, message_doc
from fabric.reference.machine import to_json_value
from fabric.schemas import REGISTRY
from fabric.sim.types import EVENT_KINDS
from fabric.wire import codec
from fabric.wire.errors import NotFound, ServiceUnavailable
from fabric.wire.keys import ENDPOINTS, TOPICS

pytestmark = pytest.mark.timeout(300)

DOCS = Path(__file__).resolve().parents[1] / "docs"
TERMINAL = re.compile(r"[.!?][)\"'`]*$")
DANGLING = re.compile(r"(?:[,;:(\-/]|\b(?:and|or|the|a|an|of|to|with|but|than|its|their))\s*$", re.I)


def _flat(text: str) -> str:
    return " ".join(text.split())


@pytest.fixture(scope="module")
def doc() -> dict:
    return json.loads((DOCS / "protocol.json").read_text())


def _validator(doc: dict, type_name: str, envelope: bool = True) -> jsonschema.Draft202012Validator:
    ref = {"$ref": f"#/$defs/{type_name}"}
    root = {"$defs": doc["$defs"], **({"allOf": [ref, {"$ref": "#/$defs/envelope"}]} if envelope else ref)}
    return jsonschema.Draft202012Validator(root)


def _check(doc: dict, type_name: str, value: dict) -> None:
    errors = sorted(_validator(doc, type_name).iter_errors(value), key=lambda e: list(e.path))
    assert not errors, f"{type_name}: " + "; ".join(f"{list(e.path)}: {e.message}" for e in errors[:5])


# --- the documents ----------------------------------------------------------------------------------------

def test_the_reference_and_its_json_are_current():
    assert (DOCS / "protocol.md").read_text() == render(), "run: python -m fabric.protocol_doc > docs/protocol.md"
    assert (DOCS / "protocol.json").read_text() == render_json(), \
        "run: python -m fabric.protocol_doc --json > docs/protocol.json"


def test_no_description_is_cut_short():
    """Every message's whole docstring and every field's whole comment reach the document; a docstring is
    sentences (it ends with terminal punctuation); no description ends on a dangling word or mark."""
    text = _flat(render().replace("\\|", "|"))             # (a table cell escapes |)
    for name, cls in REGISTRY.items():
        doc = message_doc(cls)
        assert doc, f"{name} has no docstring"
        assert TERMINAL.search(doc), f"{name}'s docstring does not end a sentence: ...{doc[-60:]!r}"
        assert _flat(doc) in text, f"{name}'s docstring is not in the document whole"
        for fd in field_docs(cls):
            assert fd.description, f"{name}.{fd.name} has no description (a comment beside the field)"
            assert not DANGLING.search(fd.description), f"{name}.{fd.name} is cut: {fd.description!r}"
            assert fd.description.count("(") == fd.description.count(")"), f"{name}.{fd.name}: {fd.description!r}"
            assert fd.description.count("``") % 2 == 0, f"{name}.{fd.name}: {fd.description!r}"
            assert _flat(fd.description) in text, f"{name}.{fd.name}'s description is not in the document whole"
    for (svc, cmd), ep in ENDPOINTS.items():
        assert ep.doc and not DANGLING.search(ep.doc), f"{svc}/{cmd}: {ep.doc!r}"
    for kind, entry in EVENTS.items():
        assert TERMINAL.search(entry.when), f"event {kind}: {entry.when!r}"
        for key, (_, what) in entry.data.items():
            assert TERMINAL.search(what), f"event {kind} data {key}: {what!r}"


def test_a_field_description_is_every_comment_line_of_it():
    class Sample:
        # a leading line
        a: int = 1      # the trailing part,
                        # and its continuation
        b: str = ""     # b alone
        # c's own
        c: float = 0.0

    got = _comments(Sample)
    assert got == {"a": "a leading line the trailing part, and its continuation", "b": "b alone", "c": "c's own"}


def test_every_seconds_field_says_its_clock():
    for name, cls in REGISTRY.items():
        for fd in field_docs(cls):
            if fd.unit == "seconds":
                assert re.search(r"wall|epoch|simulat|clock", fd.description), \
                    f"{name}.{fd.name} does not say its time base: {fd.description!r}"


def test_every_event_kind_endpoint_and_topic_is_described(doc):
    assert set(EVENTS) == set(EVENT_KINDS) == set(doc["events"])
    assert set(examples.COMMAND_EXAMPLES) == set(ENDPOINTS)
    assert set(examples.TOPIC_EXAMPLES) == set(TOPICS)
    assert {(e["service"], e["command"]) for e in doc["endpoints"]} == set(ENDPOINTS)
    assert {(t["service"], t["topic"]) for t in doc["topics"]} == set(TOPICS)
    md = render()
    for needle in ("`_v`", "common.Empty", "INTERACTIVE_HIGH", "from_layer", "plate gate", "job_next", "allowed",
                   "cmd/health", "supervisor/jobs", "since_seq", "finished print shows", "base frame", "not_found",
                   "no_cell", "offset + len(jobs)", "application/x-am-fabric-program+msgpack"):
        assert needle in md, needle


def test_the_json_description_is_a_valid_schema_and_the_examples_fit_it(doc):
    jsonschema.Draft202012Validator.check_schema(doc)
    assert doc == json.loads(json.dumps(description()))
    for ep in doc["endpoints"]:
        _check(doc, ep["request"], ep["example"]["request"])
        _check(doc, ep["reply"], ep["example"]["reply"])
    for topic in doc["topics"]:
        _check(doc, topic["payload"], topic["example"])
    bad = to_json_value(codec.unpack(codec.encode(examples.POSE)))
    bad["xyz_mm"] = "here"
    assert list(_validator(doc, "station.Pose").iter_errors(bad))          # the schemas do reject


# --- real replies -----------------------------------------------------------------------------------------

CUBE_GCODE = ("G21\nG90\nM83\nG1 Z0.4 F1200\nG1 X100 Y100 F3000\n"
              + "".join(f"G1 Z{0.4 * (k + 1):.1f}\nG1 X120 Y100 E1 F1500\nG1 X120 Y120 E1\nG1 X100 Y120 E1\n"
                        f"G1 X100 Y100 E1\n" for k in range(3))).encode()


class Raw:
    """Asks and listens with nothing but the session: the payloads as the wire carries them, validated."""

    def __init__(self, session: zenoh.Session, cell: str, doc: dict) -> None:
        self.session, self.cell, self.doc = session, cell, doc
        self.seen: set[str] = set()

    def ask(self, service: str, command: str, request: object = None, ok: bool = True) -> dict:
        ep = ENDPOINTS[(service, command)]
        payload = codec.encode(request if request is not None else ep.request())
        _check(self.doc, ep.request.TYPE, to_json_value(codec.unpack(payload)))
        replies = list(self.session.get(f"am/{self.cell}/{service}/cmd/{command}", payload=payload,
                                        timeout=ep.timeout_s, consolidation=zenoh.ConsolidationMode.NONE))
        assert len(replies) == 1, f"{service}/{command}: {len(replies)} replies"
        reply = replies[0]
        body = msgpack.unpackb((reply.ok or reply.err).payload.to_bytes())
        if reply.ok is None:
            _check(self.doc, "common.Error", to_json_value(body))
            assert not ok, f"{service}/{command}: {body}"
            return body
        _check(self.doc, ep.reply.TYPE, to_json_value(body))
        self.seen.add(f"{service}/{command}")
        return body


@pytest.fixture
def cell_in_process(session, settings, tmp_path):
    """The five services in this process on one peer session."""
    from fabric.robot.cell import Cell
    from fabric.services.collision import CollisionService
    from fabric.services.planner import PlannerService
    from fabric.services.slicer import SlicerService
    from fabric.services.station import StationService
    from fabric.services.supervisor import SupervisorService
    cell = Cell.builtin("irb140")
    services = [PlannerService(session, settings.cell, cell), CollisionService(session, settings.cell, cell),
                SlicerService(session, settings.cell, (250.0, 250.0), 250.0),
                StationService(session, settings.cell, cell, pose_hz=50.0),
                SupervisorService(session, settings.cell, tmp_path / "supervisor")]
    for svc in services:
        svc.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(deadline_s=30)
            yield client, services
    finally:
        for svc in reversed(services):
            svc.close()


def _listen(session: zenoh.Session, cell: str) -> tuple[queue.Queue, list]:
    got: queue.Queue = queue.Queue()
    subs = [session.declare_subscriber(f"am/{cell}/{svc}/{topic}",
                                       lambda smp, key=(svc, topic): got.put((key, smp.payload.to_bytes())))
            for svc, topic in TOPICS]
    return got, subs


def test_real_replies_and_publications_validate_against_the_description(cell_in_process, settings, doc):
    client, services = cell_in_process
    for svc in services:                                     # the delivery each topic is documented with
        for pub in svc._publishers:
            topic = pub.key.rsplit("/", 1)[-1]
            want = zenoh.CongestionControl.BLOCK if (svc.name, topic) in LOSSLESS else zenoh.CongestionControl.DROP
            assert pub._pub.congestion_control == want, pub.key
    got, subs = _listen(client.session, settings.cell)
    raw = Raw(client.session, settings.cell, doc)
    try:
        for svc in ("station", "slicer", "planner", "collision", "supervisor"):
            assert raw.ask(svc, "health")["state"] == "ok"
        raw.ask("station", "position")
        raw.ask("station", "cell")
        raw.ask("station", "time")
        raw.ask("station", "events", s.EventsQuery(since_seq=0, limit=10))
        raw.ask("slicer", "backends")
        raw.ask("supervisor", "status")
        raw.ask("supervisor", "jobs")
        raw.ask("collision", "check", s.CollisionRequest(q_from_deg=[0, 0, 0, 0, 90, 0], q_to_deg=[5, 10, 5, 0, 80, 0]))
        # planning G-code, then its results
        job = raw.ask("planner", "plan", s.PlanRequest(gcode=CUBE_GCODE, filename="cube.gcode",
                                                       offset_mm=[0.0, 0.0, 0.0]))["job_id"]
        status = client.wait_job("planner", job, timeout=120)
        raw.ask("planner", "job", s.JobQuery(job_id=job))
        raw.ask("planner", "cancel", s.JobCancel(job_id=job, reason="contract"))      # ended: stays as it was
        pid = status.result_id
        summary = raw.ask("planner", "summary", s.ArtifactQuery(artifact_id=pid))
        assert summary["runnable"], summary
        raw.ask("planner", "export", s.ExportRequest(program_id=pid, fmt="rapid"))
        raw.ask("planner", "export_chunk", s.ExportChunkRequest(fmt="csv", program_id=pid, limit_bytes=4096))
        raw.ask("planner", "pin", s.PinRequest(owner="contract", artifact_id=pid))
        raw.ask("planner", "pin", s.PinRequest(owner="contract", pinned=False))
        raw.ask("planner", "upload", s.UploadChunk(upload_id="contract01", offset=0, total_bytes=4, data=b"G28\n",
                                                   sha256=hashlib.sha256(b"G28\n").hexdigest()))
        art = client.session.get(f"am/{settings.cell}/planner/artifact/{pid}", timeout=30)
        body = msgpack.unpackb(next(iter(art)).ok.payload.to_bytes())
        _check(doc, "common.Artifact", to_json_value(body))
        _check(doc, "planner.ProgramMsg", to_json_value(msgpack.unpackb(body["data"])))
        # the station prints it
        raw.ask("station", "load", s.LoadRequest(program_id=pid))
        raw.ask("station", "collisions")
        raw.ask("station", "ready")
        raw.ask("station", "overrides", s.Overrides(speed_r=1.0))
        raw.ask("station", "rtf", s.StartRequest(rtf=0.0))
        raw.ask("station", "start", s.StartRequest(rtf=0.0))
        raw.ask("station", "state")
        end = time.monotonic() + 120
        while client.state().state == "printing" and time.monotonic() < end:
            time.sleep(0.1)
        assert client.state().reason == "finished"
        raw.ask("station", "mesh", s.MeshRequest(fmt="csv"))
        raw.ask("station", "beads", s.BeadsQuery(first=0, limit=100))
        raw.ask("station", "pause", ok=False)                # not printing: a state error with `allowed`
        raw.ask("station", "recover", ok=False)              # nothing interrupted
        raw.ask("station", "clear_plate")
        raw.ask("station", "start", s.StartRequest(rtf=1.0))     # again, at real time: pause, resume, stop
        raw.ask("station", "pause")
        raw.ask("station", "resume")
        since = client.events(limit=1).last_seq + 1
        raw.ask("station", "stop")
        _wait_event(client, since, "stopped")               # the robot moved clear: now it may go home
        raw.ask("station", "clear_plate")
        since = client.events(limit=1).last_seq + 1
        raw.ask("station", "home")
        _wait_event(client, since, "home")
        since = client.events(limit=1).last_seq + 1
        raw.ask("station", "jog", s.JogRequest(dxyz_mm=[0.0, 0.0, 10.0]))
        _wait_event(client, since, "jogged")
        since = client.events(limit=1).last_seq + 1        # this program heats nothing: a material extruded cold
        raw.ask("station", "extrude", s.ExtrudeRequest(length_mm=5.0, speed_mm_s=20.0))
        assert _wait_event(client, since, "extruded").data["filament_mm"] == 5.0
        # slicing a small model, sent in one piece (and a piece uploaded)
        import trimesh
        stl = trimesh.creation.box((20.0, 20.0, 4.0)).export(file_type="stl")
        raw.ask("slicer", "upload", s.UploadChunk(upload_id="contract02", offset=0, total_bytes=len(stl), data=stl,
                                                  sha256=hashlib.sha256(stl).hexdigest()))
        job = raw.ask("slicer", "slice", s.SliceRequest(model=stl, filename="box.stl"))["job_id"]
        gcode_id = client.wait_job("slicer", job, timeout=120).result_id
        raw.ask("slicer", "job", s.JobQuery(job_id=job))
        raw.ask("slicer", "cancel", s.JobCancel(job_id=job, reason="contract"))
        raw.ask("slicer", "result", s.ArtifactQuery(artifact_id=gcode_id))
        raw.ask("slicer", "pin", s.PinRequest(owner="contract", pinned=False))
        # the supervisor: a G-code job submitted with neither source nor start nor rtf
        acc = raw.ask("supervisor", "submit", s.JobSubmit(model=CUBE_GCODE, filename="cube.gcode"))
        rec = client.wait_print_job(acc["job_id"], lambda r: r.state == "loaded" or r.prepared, timeout=120)
        raw.ask("supervisor", "job", s.JobQuery(job_id=acc["job_id"]))
        raw.ask("supervisor", "job_move", s.JobMove(job_id=acc["job_id"], position=0), ok=rec.state != "queued")
        raw.ask("supervisor", "job_next")
        second = raw.ask("supervisor", "submit", s.JobSubmit(model=CUBE_GCODE, filename="second.gcode"))
        # the first job is on the station now: the second waits in the queue, where it can always be moved (the
        # first may have been loaded before it could be: a fast plan, a clear plate)
        raw.ask("supervisor", "job_move", s.JobMove(job_id=second["job_id"], position=0))
        raw.ask("supervisor", "job_remove", s.JobQuery(job_id=second["job_id"]))
        # a file uploaded to the supervisor in a piece (submitting from an upload: tests/test_protocol_as_documented.py)
        raw.ask("supervisor", "upload", s.UploadChunk(upload_id="contract03", offset=0, total_bytes=len(CUBE_GCODE),
                                                      data=CUBE_GCODE, sha256=hashlib.sha256(CUBE_GCODE).hexdigest()))
        # the file library: both files are in it; one added, shown and removed
        listed = raw.ask("supervisor", "files", s.FilesQuery(limit=10))
        assert {f["name"] for f in listed["files"]} >= {"cube.gcode", "second.gcode"}
        added = raw.ask("supervisor", "file_add", s.FileAdd(data=CUBE_GCODE, name="third.gcode"))
        raw.ask("supervisor", "file", s.FileQuery(file_id=added["file_id"][:6]))
        raw.ask("supervisor", "file_remove", s.FileQuery(file_id=added["file_id"]))
        raw.ask("supervisor", "file", s.FileQuery(file_id=added["file_id"]), ok=False)
        # every event seen so far fits its kind's documented data
        for ev in client.events(0).events:
            data = to_json_value(ev.data)
            errors = list(jsonschema.Draft202012Validator(doc["events"][ev.kind]["data"]).iter_errors(data))
            assert not errors, f"event {ev.kind} data {data}: {errors[0].message}"
        raw.ask("station", "calibrate")
    finally:
        for sub in subs:
            sub.undeclare()
    kinds = set()
    while True:
        try:
            (svc, topic), payload = got.get_nowait()
        except queue.Empty:
            break
        _check(doc, TOPICS[(svc, topic)].TYPE, to_json_value(msgpack.unpackb(payload)))
        kinds.add((svc, topic))
    assert kinds >= {("station", "pose"), ("station", "state"), ("station", "events"), ("station", "extrusion"),
                     ("station", "temps"), ("planner", "progress"), ("supervisor", "jobs")}, kinds
    missing = {f"{svc}/{cmd}" for svc, cmd in ENDPOINTS} - raw.seen - {"station/recover"}
    assert not missing, f"no real reply validated for {sorted(missing)}"


def _wait_event(client: Client, since: int, kind: str, timeout: float = 60.0) -> s.Event:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        for ev in client.events(since).events:
            if ev.kind == kind:
                return ev
        time.sleep(0.05)
    raise AssertionError(f"no {kind} event within {timeout:g} s")


def test_submit_infers_the_source_and_runs_at_real_time_and_job_next_honours_start(cell_in_process):
    client, _ = cell_in_process
    rec = client.job(client.submit(s.JobSubmit(model=CUBE_GCODE, filename="cube.GCO")).job_id)
    assert (rec.source, rec.rtf, rec.start) == ("gcode", 1.0, False)
    with pytest.raises(Exception, match="cannot tell from the file name") as err:
        client.submit(s.JobSubmit(model=CUBE_GCODE, filename="cube.txt"))
    assert err.value.details["field"] == "source"
    assert client.job(client.submit(s.JobSubmit(model=CUBE_GCODE, filename="cube.txt", source="gcode")).job_id)
    # the first job is loaded (the plate is clear) but not started: it was submitted without start
    rec = client.wait_print_job(rec.job_id, lambda r: r.state == "loaded", timeout=120)
    assert client.state().state == "ready"
    ack = client.job_next()          # the plate was clear already: nothing started, the record keeps start
    assert not client.job(rec.job_id).start and client.job(rec.job_id).state == "loaded"
    assert ack.ok
    client.start(rtf=0)              # the operator starts it
    done = client.wait_print_job(rec.job_id, lambda r: False, timeout=120)
    assert done.state == "finished" and not done.start
    # the second job waits for the plate; job next loads it and, as it was submitted without start, no more
    second = client.jobs().jobs[-1]
    second = client.wait_print_job(second.job_id, lambda r: r.waiting_for == "plate", timeout=120)
    events = client.subscribe("station", "events")
    try:
        ack = client.job_next()
        assert second.job_id in ack.message and "fabric-cli start" in ack.message, ack.message
        after = client.wait_print_job(second.job_id, lambda r: r.state == "loaded", timeout=60)
        assert not after.start
        with pytest.raises(queue.Empty):                 # a start would come right after the load: none comes
            while True:
                ev = events.get(timeout=1.0)
                assert not (ev.kind == "started" and ev.data.get("job_id") == second.job_id), ev
    finally:
        events.close()
    assert client.state().state == "ready" and client.job(second.job_id).state == "loaded"


def test_unknown_commands_and_cells_get_a_typed_answer_within_the_timeout(cell_in_process, settings):
    client, _ = cell_in_process
    for service in ("station", "supervisor", "slicer"):
        t0 = time.monotonic()
        replies = list(client.session.get(f"am/{settings.cell}/{service}/cmd/no_such", payload=b"",
                                          timeout=5.0, consolidation=zenoh.ConsolidationMode.NONE))
        assert time.monotonic() - t0 < 2.0
        assert len(replies) == 1 and replies[0].err is not None
        err = codec.decode(replies[0].err.payload.to_bytes(), s.ErrorReply)
        assert err.code == "not_found" and err.details["command"] == "no_such" and "health" in err.details["commands"]
    # a known command still has exactly one reply, and so has every service to a wildcard health query
    for _ in range(20):
        replies = list(client.session.get(f"am/{settings.cell}/station/cmd/position", timeout=5.0,
                                          payload=codec.encode(s.Empty()),
                                          consolidation=zenoh.ConsolidationMode.NONE))
        assert [r.ok is not None for r in replies] == [True]
    assert len(client.healths()) == 5
    with pytest.raises(NotFound, match="station serves"):
        client.call("station", "no_such")
    # a wrong cell: nothing answers, and the error names the cells there are
    other = Client(client.session, "nosuchcell")
    t0 = time.monotonic()
    with pytest.raises(ServiceUnavailable, match="no service of cell 'nosuchcell'") as err:
        other.call("station", "position", timeout=1.0)
    assert time.monotonic() - t0 < 2.5
    assert err.value.details["reason"] == "no_cell" and settings.cell in err.value.details["cells"]
    assert settings.cell in str(err.value)


def test_a_stopped_service_is_told_from_an_unknown_cell(session, settings):
    from fabric.robot.cell import Cell
    from fabric.services.collision import CollisionService
    svc = CollisionService(session, settings.cell, Cell.builtin("irb140"))
    svc.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("collision",), deadline_s=20)
            with pytest.raises(ServiceUnavailable, match="has no station running") as err:
                client.call("station", "state", timeout=0.5)
            assert err.value.details["reason"] == "service_down" and err.value.details["alive"] == ["collision"]
    finally:
        svc.close()


def test_the_client_package_imports_no_service_code_and_its_helpers_no_client():
    import subprocess
    import sys
    code = ("import sys, fabric.client, fabric.client.follow, fabric.client.job_waits, fabric.client.transfers\n"
            "bad = sorted(m for m in sys.modules if m.startswith('fabric.') and not m.startswith(("
            "'fabric.client', 'fabric.wire', 'fabric.schemas')))\n"
            "print(bad)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stdout + out.stderr
    root = Path(__file__).resolve().parents[1] / "fabric" / "client"
    for helper in ("job_waits.py", "transfers.py", "follow.py"):
        text = (root / helper).read_text()
        assert "from fabric.client import" not in text and "fabric.client.client" not in text, helper


def test_clear_plate_on_a_plate_without_a_bead_lets_the_waiting_job_go_on(cell_in_process):
    """A print stopped while heating laid no bead: the station sees the plate clear, but the supervisor's queue
    waits for the operator's word before the next job (a print was begun there). ``clear_plate`` is that word:
    it said "clear already" and the next job kept waiting for ``job next``; now it is noted (event
    ``plate_cleared``, no job, no volume) and the waiting job is loaded."""
    client, _ = cell_in_process
    hot = b"M109 S200\n" + CUBE_GCODE                    # heats first: time to stop before any bead
    first = client.submit(s.JobSubmit(model=hot, filename="hot.gcode", start=True)).job_id
    client.wait_print_job(first, lambda r: r.state == "printing", timeout=120)
    client.stop()
    assert client.wait_print_job(first, lambda r: False, timeout=60).state == "stopped"
    assert client.state().plate_clear and client.state().deposited_mm3 == 0.0
    second = client.submit(s.JobSubmit(model=CUBE_GCODE, filename="cube.gcode")).job_id
    client.wait_print_job(second, lambda r: r.waiting_for == "plate", timeout=120)
    since = client.events(0).last_seq
    ack = client.clear_plate()
    assert ack.ok and "clear already" in ack.message
    ev = _wait_event(client, since, "plate_cleared")
    assert ev.data == {"job_id": "", "plate_mm3": 0.0}
    assert client.wait_print_job(second, lambda r: r.state == "loaded", timeout=60).waiting_for == ""
