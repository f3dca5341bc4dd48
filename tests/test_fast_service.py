"""The service runtime and the client over the memory fabric (fast tier): typed replies and errors, unknown
commands, snapshot endpoints, telemetry, liveliness, timeouts and worker threads, with the real ``Service``
and ``Client`` and no Zenoh session. The same paths over real sessions are in test_fabric_core.py and
test_handler_workers.py."""
from __future__ import annotations

import queue
import threading
import time

import msgpack
import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.programs import content_id
from fabric.security.relay import info_key
from fabric.server.service import Service
from fabric.wire import codec
from fabric.wire.errors import (
    DecodeError,
    InternalError,
    NotFound,
    PermissionDenied,
    ServiceUnavailable,
    StateError,
    ValidationError,
)

CELL = "cell1"
WAIT_S = 5.0        # a deadline for what happens at once; never reached when the feature works


class StandInStation(Service):
    """Some of the station's endpoints, each answering one way: a reply, a typed refusal, a bug, a snapshot,
    a hold until released, and a command served by three workers."""

    name = "station"
    partial = True

    def __init__(self, session, cell: str) -> None:
        super().__init__(session, cell)
        self.pose = s.Pose(seq=7, t_sim_s=1.5, q_deg=[0.0] * 6, xyz_mm=[1.0, 2.0, 3.0],
                           quat_wxyz=[1.0, 0.0, 0.0, 0.0], base_xyz_mm=[1.0, 2.0, 3.0])
        self.current = codec.encode(s.StationState(state="idle"))
        self.release = threading.Event()          # what "time" and a long "events" wait for
        self.holding = threading.Event()          # set while a long "events" is held
        self.pub_state = self.publisher("state")
        self.handle("position", lambda _: self.pose)
        self.handle("home", self.on_home)
        self.handle("jog", self.on_jog)
        self.handle("extrude", lambda req: s.Ack(message=f"pushed {req.length_mm:g} mm"))
        self.handle("time", self.on_time)
        self.handle("events", self.on_events, workers=3)
        self.handle_snapshot("state", lambda: self.current)

    def on_home(self, _: s.Empty) -> s.Ack:
        raise StateError("the station is printing: stop it first", state="printing", command="home")

    def on_jog(self, _: s.JogRequest) -> s.Ack:
        raise KeyError("a bug")

    def on_time(self, _: s.Empty) -> s.TimeInfo:
        self.release.wait(WAIT_S)
        return s.TimeInfo(elapsed_s=0.0, total_s=1.0, remaining_s=1.0, estimate_s=1.0)

    def on_events(self, req: s.EventsQuery) -> s.EventList:
        if req.since_seq > 0:                      # a long one: held until released
            self.holding.set()
            self.release.wait(WAIT_S)
        return s.EventList(events=[], next_seq=req.since_seq)


@pytest.fixture
def station(memory_fabric):
    svc = StandInStation(memory_fabric.session(), CELL)
    svc.start()
    yield svc
    svc.release.set()
    svc.close()


@pytest.fixture
def client(memory_fabric):
    return Client(memory_fabric.session(), CELL)


def test_a_reply_is_the_handlers_typed_message(station, client):
    pose = client.position()
    assert isinstance(pose, s.Pose) and (pose.seq, pose.xyz_mm) == (7, [1.0, 2.0, 3.0])
    assert client.extrude(5.0).message == "pushed 5 mm"


def test_a_refusal_is_the_typed_error_with_its_details(station, client):
    with pytest.raises(StateError, match="printing") as e:
        client.home()
    assert e.value.details == {"state": "printing", "command": "home"}
    assert station.degraded is None                       # a refusal is not a fault


def test_a_bug_is_answered_as_internal_and_degrades_the_service(station, client):
    with pytest.raises(InternalError, match="KeyError"):
        client.jog(1.0)
    health = client.health("station")
    assert health.state == "degraded" and health.reasons[0].startswith("handler:jog: KeyError")
    assert client.position().seq == 7                     # and it keeps serving


def test_garbage_and_invalid_fields_are_typed_errors_naming_the_schema(station, client):
    key = client.keys.cmd("station", "extrude")
    for garbage in (b"\xc1\xff garbage", msgpack.packb([1, 2, 3])):
        replies = list(client.session.get(key, payload=garbage, timeout=WAIT_S))
        assert len(replies) == 1 and codec.decode(replies[0].err.payload.to_bytes(), s.ErrorReply).code == "decode"
    too_fast = codec.pack({"_t": "station.ExtrudeRequest", "_v": 1, "length_mm": 5.0, "speed_mm_s": 99.0})
    with pytest.raises(ValidationError) as e:
        client.call_raw("station", "extrude", too_fast, s.Ack, WAIT_S)
    assert e.value.details["field"] == "speed_mm_s"
    assert station.degraded is None


def test_a_command_not_served_is_not_found_naming_the_commands_served(station, client):
    with pytest.raises(NotFound, match="no command 'calibrate'") as e:
        client.calibrate()                                 # in the table, not served by this stand-in
    assert "position" in e.value.details["commands"] and "calibrate" not in e.value.details["commands"]
    replies = list(client.session.get(client.keys.cmd("station", "nope"), timeout=WAIT_S))
    err = codec.decode(replies[0].err.payload.to_bytes(), s.ErrorReply)
    assert (len(replies), err.code, err.details["command"]) == (1, "not_found", "nope")
    with pytest.raises(NotFound, match="station serves"):
        client.call("station", "nope")                     # not in the table: refused before asking


def test_a_snapshot_endpoint_answers_the_current_snapshot(station, client):
    assert client.state().state == "idle"
    station.current = codec.encode(s.StationState(state="printing", job_id="j1"))
    st = client.state()
    assert (st.state, st.job_id) == ("printing", "j1")
    replies = list(client.session.get(client.keys.cmd("station", "state"), payload=b"\x00", timeout=WAIT_S))
    assert codec.decode(replies[0].err.payload.to_bytes(), s.ErrorReply).code == "decode"


def test_a_service_that_does_not_answer_in_time_is_unavailable(station, client):
    t0 = time.monotonic()
    with pytest.raises(ServiceUnavailable, match="did not answer") as e:
        client.call("station", "time", timeout=0.3)
    assert 0.3 <= e.value.details["timeout_s"] <= time.monotonic() - t0 + 0.01
    station.release.set()
    assert client.time().total_s == 1.0                   # the held query answered; the next one too


def test_a_command_with_several_workers_answers_while_one_is_held(station, client):
    held = threading.Thread(target=lambda: client.events(since_seq=5), daemon=True)
    held.start()
    assert station.holding.wait(WAIT_S)
    assert client.call("station", "events", s.EventsQuery(since_seq=0), timeout=1.0).events == []
    station.release.set()
    held.join(WAIT_S)
    assert not held.is_alive()


def test_telemetry_is_decoded_and_checked_by_the_subscriber(station, client, memory_fabric):
    sub = client.subscribe("station", "state")
    try:
        station.pub_state.send(s.StationState(state="paused", reason="by hand"))
        got = sub.get(timeout=WAIT_S)
        assert (got.state, got.reason) == ("paused", "by hand")
        with pytest.raises(TypeError, match=r"station\.State"):
            station.pub_state.send(s.Ack())
        station.pub_state.send_encoded(b"\x00garbage")
        with pytest.raises(DecodeError):
            sub.get(timeout=WAIT_S)
    finally:
        sub.close()


def test_liveliness_follows_the_service(memory_fabric, client):
    changes = client.subscribe_alive()
    pushed: queue.Queue[tuple[str, bool]] = queue.Queue()
    console = client.subscribe_alive(lambda name, alive: pushed.put((name, alive)))     # as the console does
    try:
        assert not client.alive(timeout=0.2)["station"]
        svc = StandInStation(memory_fabric.session(), CELL)
        svc.start()
        client.wait_alive(("station",), deadline_s=WAIT_S)
        assert changes.get(timeout=WAIT_S) == ("station", True) and pushed.get(timeout=WAIT_S) == ("station", True)
        assert client.cells() == {CELL: ["station"]}
        svc.close()
        assert changes.get(timeout=WAIT_S) == ("station", False)
        assert pushed.get(timeout=WAIT_S) == ("station", False)
        assert not client.alive(timeout=0.2)["station"]
    finally:
        changes.close()
        console.close()


def test_a_second_station_of_the_cell_refuses_to_start(station, memory_fabric):
    other = StandInStation(memory_fabric.session(), CELL)
    try:
        with pytest.raises(StateError, match="already serving cell"):
            other.start()
    finally:
        other.close()
    elsewhere = StandInStation(memory_fabric.session(), "cell2")          # another cell's is welcome
    elsewhere.start()
    elsewhere.close()


def test_an_artifact_is_served_by_its_id(station, client):
    data = b"G1 X1\n"
    art_id = station.store_artifact(s.Artifact(artifact_id=content_id(data), name="a.gcode",
                                               media_type="text/x-gcode", data=data))
    assert client.artifact("station", art_id).data == data
    with pytest.raises(NotFound, match="no artifact"):
        client.artifact("station", "0" * 64, timeout=WAIT_S)


def test_nothing_serving_says_whether_the_cell_or_the_service_is_missing(station, memory_fabric):
    with pytest.raises(ServiceUnavailable) as e:
        Client(memory_fabric.session(), CELL).call("planner", "job", s.JobQuery(job_id="j"), timeout=1.0)
    assert (e.value.details["reason"], e.value.details["alive"]) == ("service_down", ["station"])
    with pytest.raises(ServiceUnavailable) as e:
        Client(memory_fabric.session(), "typo").position()
    assert e.value.details["reason"] == "no_cell" and e.value.details["cells"] == {CELL: ["station"]}


def test_a_secured_relay_refuses_what_a_monitor_may_not_do(memory_fabric):
    relay = memory_fabric.session()
    info = msgpack.packb({"listen": ["tcp/10.0.0.9:7448"], "hub": ["tcp/10.0.0.1:7447"], "rights": "monitor"})
    relay.declare_queryable(info_key(str(memory_fabric.zid)), lambda q: q.reply(q.key_expr, info))
    t0 = time.monotonic()
    with pytest.raises(PermissionDenied, match=r"relay at tcp/10\.0\.0\.9:7448 may not pass station/home"):
        Client(memory_fabric.session(), CELL).home()
    assert time.monotonic() - t0 < 1.0                    # said at once, not after the discovery window

