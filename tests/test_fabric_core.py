"""Runtime, client and config over real in-process Zenoh sessions on loopback."""
from __future__ import annotations

import argparse
import queue
import threading
import time

import msgpack
import pytest
import zenoh

from fabric import schemas as s
from fabric.client import Client
from fabric.services.supervisor import SupervisorService
from fabric.wire import codec
from fabric.wire.config import SessionSettings, add_session_args, settings_from_args, zenoh_config
from fabric.wire.errors import DecodeError, NotFound, ServiceUnavailable, ValidationError
from fabric.wire.keys import ENDPOINTS, Keys, parse_alive


@pytest.fixture
def supervisor(session, settings, client):
    svc = SupervisorService(session, settings.cell)
    svc.start()
    client.wait_alive(("supervisor",), deadline_s=10)   # its token follows its queryables
    yield svc
    svc.close()


@pytest.fixture
def client(hub, settings):
    with Client.connect(settings) as c:
        yield c


def test_peers_exchange_queries_and_samples(peers):
    a, b = peers
    q = a.declare_queryable("am/x/ping", handler=zenoh.handlers.FifoChannel(8))

    def serve():
        for query in q:                                   # ends when the queryable is undeclared
            with query:
                query.reply(query.key_expr, b"pong")
    t = threading.Thread(target=serve, daemon=True)
    t.start()
    sub = b.declare_subscriber("am/x/sample", handler=zenoh.handlers.FifoChannel(8))
    replies: list[bytes] = []
    deadline = time.monotonic() + 30.0
    while not replies:          # the queryable's declaration reaches b shortly after the link is up
        assert time.monotonic() < deadline
        replies = [r.ok.payload.to_bytes() for r in b.get("am/x/ping", timeout=0.5) if r.ok]
    assert replies == [b"pong"]
    while (got := sub.try_recv()) is None:               # and samples flow the other way
        assert time.monotonic() < deadline
        a.put("am/x/sample", b"hello")
        list(b.get("am/x/ping", timeout=0.5))            # a round trip paces the loop (no sleep)
    assert got.payload.to_bytes() == b"hello"
    q.undeclare()


def test_garbage_gets_an_error_reply_and_the_service_keeps_serving(supervisor, client):
    key = client.keys.cmd("supervisor", "status")
    for garbage in (b"", b"\xc1\xff garbage", msgpack.packb([1, 2, 3]), msgpack.packb({"_t": "nope", "_v": 1})):
        replies = list(client.session.get(key, payload=garbage, timeout=5.0))
        assert len(replies) == 1 and replies[0].err is not None
        err = codec.decode(replies[0].err.payload.to_bytes(), s.ErrorReply)
        assert err.code == "decode" and err.message
    st = client.status()
    assert st.cell == client.keys.cell
    assert {i.name for i in st.services} == {"station", "slicer", "planner", "collision", "supervisor"}
    assert supervisor.degraded is None


def test_invalid_field_is_a_validation_error_naming_it(supervisor, client):
    bad = codec.pack({"_t": "supervisor.JobSubmit", "_v": 1, "model": b"x", "filename": "a.stl", "rtf": -3.0})
    with pytest.raises(ValidationError) as e:
        client.call_raw("supervisor", "submit", bad, s.JobAccepted, 5.0)
    assert e.value.details["field"] == "rtf"


def test_unknown_job_is_not_found(supervisor, client):
    with pytest.raises(NotFound, match="no job deadbeef"):
        client.job("deadbeef")


def test_no_service_is_unavailable_within_the_timeout(client):
    t0 = time.monotonic()
    with pytest.raises(ServiceUnavailable, match="no station/position on the fabric") as e:
        client.call("station", "position", timeout=0.3)
    assert e.value.details["timeout_s"] <= time.monotonic() - t0 + 0.01        # says what it really waited


def test_a_service_that_does_not_answer_is_unavailable_not_undecodable(session, client):
    held: list = []
    q = session.declare_queryable(client.keys.cmd("station", "position"), handler=zenoh.handlers.FifoChannel(8))

    def hold() -> None:                     # takes the query and answers nothing (a frozen service)
        held.append(q.recv())
    threading.Thread(target=hold, daemon=True).start()
    try:
        t0 = time.monotonic()
        with pytest.raises(ServiceUnavailable, match="did not answer") as e:
            client.call("station", "position", timeout=0.5)
        waited = time.monotonic() - t0
        assert 0.4 <= e.value.details["timeout_s"] <= waited + 0.01
    finally:
        for query in held:
            query.drop()
        q.undeclare()


def test_liveliness_reports_alive_and_gone(session, settings, client):
    assert not client.alive(timeout=0.3)["supervisor"]
    svc = SupervisorService(session, settings.cell)
    svc.start()
    client.wait_alive(("supervisor",), deadline_s=10)
    assert client.alive(timeout=5.0)["supervisor"]     # returns as soon as the hub has answered
    svc.close()                                  # undeclares the token: gone for everyone, promptly
    deadline = time.monotonic() + 10.0
    while True:                                  # bounded: the undeclaration travels through the hub
        try:
            client.wait_alive(("supervisor",), deadline_s=0.5)
        except ServiceUnavailable as err:
            assert err.details["missing"] == ["supervisor"]
            break
        assert time.monotonic() < deadline, "token still visible 10 s after the service closed"


def test_supervisor_tracks_liveliness(supervisor, session, settings, client):
    def planner_alive() -> bool:
        return {i.name: i.alive for i in client.status().services}["planner"]

    assert not planner_alive()
    token = session.liveliness().declare_token(Keys(settings.cell).alive("planner"))
    deadline = time.monotonic() + 5.0
    while not planner_alive():                    # the supervisor's liveliness subscriber saw it appear
        assert time.monotonic() < deadline
    token.undeclare()
    deadline = time.monotonic() + 5.0
    while planner_alive():                        # ... and disappear
        assert time.monotonic() < deadline


def test_subscription_decodes_and_validates(session, settings, client):
    sub = client.subscribe("station", "state")
    pub = session.declare_publisher(Keys(settings.cell).topic("station", "state"))
    try:
        for _ in range(100):
            pub.put(codec.encode(s.StationState(state="idle")))
            try:
                msg = sub.get(timeout=0.05)
                break
            except queue.Empty:
                continue
        assert msg.state == "idle"
        pub.put(b"\x00garbage")
        with pytest.raises(DecodeError):
            while True:
                sub.get(timeout=2.0)
    finally:
        sub.close()
        pub.undeclare()


def test_endpoint_table_and_keys_are_consistent():
    keys = Keys("cellA")
    for (service, command), ep in ENDPOINTS.items():
        assert keys.cmd(service, command) == f"am/cellA/{service}/cmd/{command}"
        assert ep.timeout_s > 0 and hasattr(ep.request, "TYPE") and hasattr(ep.reply, "TYPE")
    assert parse_alive(keys.alive("station")) == ("cellA", "station")
    assert keys.parse_artifact(keys.artifact("planner", "ab12")) == "ab12"
    with pytest.raises(ValueError):
        Keys("bad/cell")


def test_session_settings_from_flags():
    p = argparse.ArgumentParser()
    add_session_args(p)
    st = settings_from_args(p.parse_args(["--mode", "client", "--connect", "tcp/10.0.0.2:7447", "--cell", "c9"]))
    assert (st.mode, st.connect, st.cell) == ("client", ["tcp/10.0.0.2:7447"], "c9")
    assert "--connect" in st.to_args()
    conf = zenoh_config(SessionSettings(listen=["tcp/127.0.0.1:0"], connect=[]))
    assert "tcp/127.0.0.1:0" in conf.get_json("listen/endpoints")
    assert conf.get_json("scouting/multicast/enabled") == "false"


def test_subscribe_alive_reports_services_coming_and_going(session, settings, client):
    changes = client.subscribe_alive()
    try:
        token = session.liveliness().declare_token(Keys(settings.cell).alive("slicer"))
        assert changes.get(timeout=10.0) == ("slicer", True)
        token.undeclare()
        assert changes.get(timeout=10.0) == ("slicer", False)
    finally:
        changes.close()
    seen: queue.Queue[tuple[str, bool]] = queue.Queue()
    pushed = client.subscribe_alive(lambda name, alive: seen.put((name, alive)))     # as the console does
    try:
        token = session.liveliness().declare_token(Keys(settings.cell).alive("collision"))
        assert seen.get(timeout=10.0) == ("collision", True)
        token.undeclare()
        assert seen.get(timeout=10.0) == ("collision", False)
    finally:
        pushed.close()


def test_cmd_all_matches_every_command_of_a_service_only():
    keys = Keys("cellA")
    pattern = zenoh.KeyExpr(keys.cmd_all("planner"))
    for service, command in ENDPOINTS:
        assert pattern.intersects(zenoh.KeyExpr(keys.cmd(service, command))) == (service == "planner")


def test_a_failed_job_carries_a_typed_error_the_client_raises_again():
    from fabric.server.jobs import JobRunner
    from fabric.wire.errors import UnreachableError, error_from_code

    def fail(job):
        raise UnreachableError("G-code line 6 is out of reach", reason="out of reach", gcode_line=6, row=3)

    def bug(job):
        raise KeyError("oops")

    runner = JobRunner("test", None)
    try:
        bad, broken = runner.submit("plan", fail), runner.submit("plan", bug)
        runner.close()                                       # the worker finishes the queue, then stops
        assert bad.state == "failed" and isinstance(bad.error, s.ErrorReply)
        assert bad.error.code == "unreachable" and bad.error.details == {"reason": "out of reach",
                                                                          "gcode_line": 6, "row": 3}
        back = codec.decode(codec.encode(bad), s.JobStatus)
        assert back.error == bad.error
        again = error_from_code(back.error.code, back.error.message, back.error.details)   # as Client.wait_job does
        assert isinstance(again, UnreachableError) and again.details["reason"] == "out of reach"
        assert broken.state == "failed" and broken.error.code == "internal" and "KeyError" in broken.message
    finally:
        runner.close()


def test_a_command_reply_is_used_before_the_service_finishes_the_query(session, client):
    """The reply is handed over on arrival, not held until the query's final message (the service here
    keeps the query open until the caller has its answer: a held reply would come only when it closes)."""
    answered, finished = threading.Event(), threading.Event()
    q = session.declare_queryable(client.keys.cmd("station", "position"), handler=zenoh.handlers.FifoChannel(8))
    pose = s.Pose(seq=7, t_sim_s=0.0, q_deg=[0.0] * 6, xyz_mm=[1.0, 2.0, 3.0], quat_wxyz=[1.0, 0.0, 0.0, 0.0],
                  base_xyz_mm=[1.0, 2.0, 3.0])

    def serve() -> None:
        query = q.recv()
        query.reply(query.key_expr, codec.encode(pose), express=True)
        answered.wait(10.0)                 # the query stays open until the caller has its answer
        finished.set()
        query.drop()
    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        got = client.call("station", "position", timeout=30.0)
        assert not finished.is_set()
        assert (got.seq, got.xyz_mm) == (7, [1.0, 2.0, 3.0])
    finally:
        answered.set()
        t.join(10.0)
        q.undeclare()
