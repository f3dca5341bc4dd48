"""Conformance: a client that knows nothing of this project but docs/protocol.md and docs/protocol.json (zenoh and
msgpack only, in a process of its own whose modules are checked) drives a print end to end against a cell of
processes: it lists the services, reads position and state, follows pose and events without gaps, submits a
G-code job, starts, pauses, resumes and stops it, and sees the job record end ``stopped``."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from fabric.cli.up import CellProcesses

from support.loopback import make_settings

pytestmark = pytest.mark.timeout(400)

PROTOCOL_JSON = Path(__file__).resolve().parents[1] / "docs" / "protocol.json"

# Written from the reference's examples; imports nothing but the standard library, zenoh and msgpack.
CLIENT = r'''
import json, queue, sys, time
BEFORE = set(sys.modules)                     # what the interpreter's start-up loaded (site hooks)
import msgpack, zenoh

endpoints, cell, reference_path = json.loads(sys.argv[1]), sys.argv[2], sys.argv[3]
reference = json.load(open(reference_path))
EXAMPLES = {f"{e['service']}/{e['command']}": e for e in reference["endpoints"]}
report = {"steps": []}


def step(text):
    report["steps"].append(text)
    print(text, file=sys.stderr, flush=True)


def request(name, **fields):
    """The example request of a command (tags and every field), with ``fields`` changed."""
    body = dict(EXAMPLES[name]["example"]["request"])
    body.update(fields)
    return msgpack.packb(body, use_bin_type=True)


def ask(session, name, payload=None):
    ep = EXAMPLES[name]
    q = ep["qos"]
    kwargs = {"payload": payload if payload is not None else request(name), "timeout": ep["timeout_s"]}
    if q["priority"] == "INTERACTIVE_HIGH":
        kwargs.update(priority=zenoh.Priority.INTERACTIVE_HIGH, express=q["express"],
                      consolidation=zenoh.ConsolidationMode.NONE)
    key = ep["key"].replace("{cell}", cell)
    for reply in session.get(key, **kwargs):
        if reply.ok is not None:
            body = msgpack.unpackb(reply.ok.payload.to_bytes())
            assert body["_t"] == ep["reply"], (name, body)
            return body
        err = msgpack.unpackb(reply.err.payload.to_bytes())
        raise RuntimeError(f"{name}: [{err['code']}] {err['message']}")
    raise TimeoutError(name)


class Stream:
    """One topic's messages, decoded in this thread."""

    def __init__(self, session, topic):
        self.q = queue.Queue()
        self.seen = []                                # every message's seq, in arrival order
        self.sub = session.declare_subscriber(f"am/{cell}/{topic}", lambda s: self.q.put(s.payload.to_bytes()))

    def until(self, test, timeout=60.0):
        end = time.monotonic() + timeout
        while True:
            left = end - time.monotonic()
            if left <= 0:
                raise TimeoutError("nothing came that passes the test")
            msg = msgpack.unpackb(self.q.get(timeout=left))
            self.seen.append(msg.get("seq"))
            if test(msg):
                return msg


conf = zenoh.Config()
conf.insert_json5("mode", json.dumps("client"))
conf.insert_json5("connect/endpoints", json.dumps(endpoints))
conf.insert_json5("scouting/multicast/enabled", "false")
with zenoh.open(conf) as session:
    # who is up: the liveliness tokens
    alive = sorted(str(r.ok.key_expr).rsplit("/", 1)[1] for r in session.liveliness().get(f"am/{cell}/alive/*",
                                                                                          timeout=5.0) if r.ok)
    report["services"] = alive
    step(f"alive: {alive}")
    pose = ask(session, "station/position")
    state = ask(session, "station/state")
    report["position"] = {k: pose[k] for k in ("xyz_mm", "base_xyz_mm", "q_deg")}
    report["state0"] = state["state"]
    step(f"station {state['state']} at {pose['xyz_mm']}")

    # follow pose and events from now on (every message kept, to check the numbering)
    poses = []
    session.declare_subscriber(f"am/{cell}/station/pose",
                               lambda s: poses.append(msgpack.unpackb(s.payload.to_bytes())["seq"]))
    event_stream = Stream(session, "station/events")
    jobs = Stream(session, "supervisor/jobs")
    first_seq = ask(session, "station/events", request("station/events", since_seq=0, limit=1))["last_seq"] + 1

    def event(kind, job_id, timeout=60.0):
        got = event_stream.until(lambda e: e["kind"] == kind and e["data"].get("job_id") == job_id, timeout)
        step(f"event {got['seq']} {kind}")
        return got

    # a G-code job: the submit example, with the file; source from its name, start off, real time
    gcode = "G21\nG90\nM83\nG1 Z0.4 F1200\nG1 X100 Y100 F3000\n" + "".join(
        f"G1 Z{0.4 * (k + 1):.1f}\nG1 X140 Y100 E2 F1200\nG1 X140 Y140 E2\nG1 X100 Y140 E2\nG1 X100 Y100 E2\n"
        for k in range(12))
    submit = dict(EXAMPLES["supervisor/submit"]["example"]["request"])
    submit.update(model=gcode.encode(), filename="conformance.gcode", start=False, rtf=1.0)
    del submit["source"]                                 # not given: the supervisor takes it from the name
    job_id = ask(session, "supervisor/submit", msgpack.packb(submit, use_bin_type=True))["job_id"]
    step(f"submitted job {job_id}")
    record = ask(session, "supervisor/job", request("supervisor/job", job_id=job_id))
    report["source"] = record["source"]
    if record["state"] != "loaded":
        record = jobs.until(lambda r: r["job_id"] == job_id and (r["state"] in ("loaded", "failed")
                                                                  or r["waiting_for"] == "plate"), 180.0)
    if record["waiting_for"] == "plate":                  # a part from before is on the plate: it is taken off
        step(ask(session, "supervisor/job_next")["message"])
        record = jobs.until(lambda r: r["job_id"] == job_id and r["state"] in ("loaded", "failed"), 60.0)
    assert record["state"] == "loaded", record
    report["loaded_start"] = record["start"]
    step("loaded; starting")

    ask(session, "station/start", request("station/start", rtf=1.0, from_layer=-1))
    event("started", job_id)
    event("layer", job_id, 60.0)
    step(ask(session, "station/pause")["message"])
    event("paused", job_id)
    report["paused_state"] = ask(session, "station/state")["state"]
    step(ask(session, "station/resume", request("station/resume", rtf=1.0))["message"])
    event("resumed", job_id)
    step(ask(session, "station/stop")["message"])
    stopped = event("stopped", job_id)
    report["stopped_data"] = sorted(stopped["data"])
    record = jobs.until(lambda r: r["job_id"] == job_id and r["state"] == "stopped", 30.0)
    report["job"] = {k: record[k] for k in ("state", "source", "rtf", "start", "deposited_mm3")}

    # the events without gaps: what the stream brought, completed from the log where it missed any
    while True:
        try:
            event_stream.seen.append(msgpack.unpackb(event_stream.q.get_nowait())["seq"])
        except queue.Empty:
            break
    streamed = event_stream.seen
    report["stream_event_gaps"] = sum(1 for a, b in zip(streamed, streamed[1:]) if b != a + 1)
    history = ask(session, "station/events", request("station/events", since_seq=first_seq, limit=100000))
    logged = [e["seq"] for e in history["events"]]
    report["event_seqs"] = [first_seq, history["last_seq"], len(logged)]
    report["event_gaps"] = [s for s in range(first_seq, history["last_seq"] + 1) if s not in set(logged)]
    report["kinds"] = sorted({e["kind"] for e in history["events"]})
    report["poses"] = len(poses)
    report["pose_gaps"] = sum(1 for a, b in zip(poses, poses[1:]) if b != a + 1)

report["fabric_modules"] = sorted(m for m in sys.modules if m == "fabric" or m.startswith("fabric."))
report["third_party"] = sorted(m for m in {m.split(".")[0] for m in set(sys.modules) - BEFORE}
                               - set(sys.stdlib_module_names) if not m.startswith("_") and m != "cython_runtime")
print(json.dumps(report))
'''


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    """A cell of its own: the five services as processes (no other test's jobs in its queue)."""
    procs = CellProcesses(make_settings(), log_dir=Path(tmp_path_factory.mktemp("conformance-logs")),
                          data_dir=Path(tmp_path_factory.mktemp("conformance-data")))
    procs.start(deadline_s=90.0)
    yield procs
    procs.stop()


def test_a_client_from_the_reference_alone_drives_a_print(cell, tmp_path):
    script = tmp_path / "plain_client.py"
    script.write_text(CLIENT)
    settings = cell.client_settings
    res = subprocess.run([sys.executable, "-I", str(script), json.dumps(settings.connect), settings.cell,
                          str(PROTOCOL_JSON)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-4000:]
    report = json.loads(res.stdout.strip().splitlines()[-1])
    assert report["fabric_modules"] == [], report["fabric_modules"]                # nothing of this project
    assert set(report["third_party"]) <= {"zenoh", "msgpack"}, report["third_party"]
    assert report["services"] == sorted(["station", "slicer", "planner", "collision", "supervisor"])
    assert len(report["position"]["xyz_mm"]) == 3 and len(report["position"]["q_deg"]) == 6
    assert report["source"] == "gcode" and report["loaded_start"] is False     # inferred; not started by itself
    assert report["paused_state"] == "paused"
    assert report["job"]["state"] == "stopped" and report["job"]["rtf"] == 1.0
    assert {"started", "layer", "paused", "resumed", "stopped"} <= set(report["kinds"])
    assert {"elapsed_s", "extruded_mm3", "filament_mm", "beads", "job_id"} <= set(report["stopped_data"])
    assert report["event_gaps"] == [] and report["event_seqs"][2] >= 5 and report["stream_event_gaps"] == 0
    assert report["poses"] > 50 and report["pose_gaps"] == 0, report
