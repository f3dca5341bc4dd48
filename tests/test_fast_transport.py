"""The memory fabric behaves as Zenoh does where the services and the client depend on it (fast tier: no
session, no process). Each behaviour here was measured against zenoh 1.10 on real sessions."""
from __future__ import annotations

import queue
import threading
import time

import pytest
import zenoh

from fabric.client import wait_connected
from fabric.wire.memory import BlockedCallback, MemoryFabric

WAIT_S = 5.0        # a deadline for what happens at once; never reached when the feature works


def serve_in_thread(queryable, answer) -> threading.Thread:
    """A worker taking queries from ``queryable``'s channel, as ``Service`` runs them."""
    def run() -> None:
        for query in queryable:
            with query:
                answer(query)
    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    return worker


def test_a_query_reaches_the_queryables_whose_key_intersects(memory_fabric):
    a, b = memory_fabric.session(), memory_fabric.session()
    for key in ("am/c1/station/cmd/position", "am/c1/station/cmd/**", "am/c2/station/cmd/position",
                "am/@relay/hub"):
        a.declare_queryable(key, lambda q, key=key: q.reply(q.key_expr, key.encode()))

    def asked(key: str) -> list[bytes]:        # every reply (the default consolidation keeps one per key)
        replies = b.get(key, timeout=WAIT_S, consolidation=zenoh.ConsolidationMode.NONE)
        return sorted(r.ok.payload.to_bytes() for r in replies if r.ok is not None)

    assert asked("am/c1/station/cmd/position") == [b"am/c1/station/cmd/**", b"am/c1/station/cmd/position"]
    assert asked("am/*/station/cmd/position") == [b"am/c1/station/cmd/**", b"am/c1/station/cmd/position",
                                                 b"am/c2/station/cmd/position"]
    assert asked("am/**") == [b"am/c1/station/cmd/**", b"am/c1/station/cmd/position",
                              b"am/c2/station/cmd/position"]      # a verbatim @ chunk is not matched by **
    assert asked("am/@relay/hub") == [b"am/@relay/hub"]


def test_queries_are_answered_on_other_threads_than_the_callers(memory_fabric):
    a, b = memory_fabric.session(), memory_fabric.session()
    threads: list[threading.Thread] = []

    def answer(query) -> None:
        threads.append(threading.current_thread())
        query.reply(query.key_expr, b"ok")
    serve_in_thread(a.declare_queryable("am/c/x/worker", handler=zenoh.handlers.FifoChannel(8)), answer)
    a.declare_queryable("am/c/x/callback", answer)
    for key in ("am/c/x/worker", "am/c/x/callback"):
        assert [r.ok.payload.to_bytes() for r in b.get(key, timeout=WAIT_S)] == [b"ok"]
    assert len(threads) == 2 and threading.current_thread() not in threads


def test_a_get_that_finds_no_queryable_ends_at_once(memory_fabric):
    t0 = time.monotonic()
    assert list(memory_fabric.session().get("am/c/nobody", timeout=WAIT_S)) == []
    assert time.monotonic() - t0 < 1.0


def test_a_query_not_finished_in_time_gets_zenohs_timeout_error(memory_fabric):
    a, b = memory_fabric.session(), memory_fabric.session()
    held: list = []
    a.declare_queryable("am/c/frozen", held.append)          # keeps the query: never finalized
    t0 = time.monotonic()
    replies = list(b.get("am/c/frozen", timeout=0.3))
    waited = time.monotonic() - t0
    assert [r.err.payload.to_bytes() for r in replies] == [b"Timeout"] and replies[0].ok is None
    assert 0.3 <= waited < 2.0
    held.clear()


def test_without_consolidation_a_reply_is_handed_over_before_the_query_ends(memory_fabric):
    a, b = memory_fabric.session(), memory_fabric.session()
    release = threading.Event()

    def answer(query) -> None:
        query.reply(query.key_expr, b"first")
        release.wait(WAIT_S)                  # the query stays open until the caller has the reply
        query.reply(query.key_expr, b"second")
    serve_in_thread(a.declare_queryable("am/c/slow", handler=zenoh.handlers.FifoChannel(8)), answer)
    replies = b.get("am/c/slow", timeout=WAIT_S, consolidation=zenoh.ConsolidationMode.NONE)
    assert next(replies).ok.payload.to_bytes() == b"first"
    release.set()
    assert [r.ok.payload.to_bytes() for r in replies] == [b"second"]


def test_by_default_the_last_reply_per_key_comes_when_the_query_ends(memory_fabric):
    a, b = memory_fabric.session(), memory_fabric.session()

    def answer(query) -> None:
        query.reply(query.key_expr, b"first")
        query.reply(query.key_expr, b"second")
    serve_in_thread(a.declare_queryable("am/c/twice", handler=zenoh.handlers.FifoChannel(8)), answer)
    assert [r.ok.payload.to_bytes() for r in b.get("am/c/twice", timeout=WAIT_S)] == [b"second"]


def test_a_reply_off_the_querys_key_or_after_the_query_ended_is_refused(memory_fabric):
    a, b = memory_fabric.session(), memory_fabric.session()
    refused: queue.Queue[str] = queue.Queue()

    def answer(query) -> None:
        for key in ("am/elsewhere", "am/c/q"):
            try:
                query.reply(key, b"x")
            except zenoh.ZError as exc:
                refused.put(f"{key}: {exc}")
        query.drop()
        try:
            query.reply("am/c/q", b"late")
        except zenoh.ZError as exc:
            refused.put(str(exc))
    serve_in_thread(a.declare_queryable("am/c/q", handler=zenoh.handlers.FifoChannel(8)), answer)
    assert [r.ok.payload.to_bytes() for r in b.get("am/c/q", timeout=WAIT_S)] == [b"x"]
    assert "does not intersect" in refused.get(timeout=WAIT_S)
    assert refused.get(timeout=WAIT_S) == "Dropped query"


def test_an_error_reply_carries_its_payload(memory_fabric):
    a, b = memory_fabric.session(), memory_fabric.session()
    a.declare_queryable("am/c/bad", lambda q: q.reply_err(b"no such thing"))
    replies = list(b.get("am/c/bad", payload=b"req", timeout=WAIT_S))
    assert [(r.ok, r.err.payload.to_bytes()) for r in replies] == [(None, b"no such thing")]


def test_a_callback_that_raises_is_logged_and_its_query_ends():
    with MemoryFabric() as fabric:
        a, b = fabric.session(), fabric.session()

        def broken(query) -> None:
            raise KeyError("oops")
        a.declare_queryable("am/c/broken", broken)
        t0 = time.monotonic()
        assert list(b.get("am/c/broken", timeout=WAIT_S)) == []
        assert time.monotonic() - t0 < 1.0                  # not held until the timeout
        assert fabric.drain()
        assert [type(e) for e in fabric.callback_errors] == [KeyError]


def test_a_callback_may_not_wait_on_the_fabric():
    with MemoryFabric() as fabric:
        a, b = fabric.session(), fabric.session()
        a.declare_queryable("am/c/inner", lambda q: q.reply(q.key_expr, b"x"))
        a.declare_subscriber("am/c/tick", lambda sample: a.get("am/c/inner", timeout=1.0))
        b.put("am/c/tick", b"")
        assert fabric.drain()
        assert [type(e) for e in fabric.callback_errors] == [BlockedCallback]


def test_samples_reach_matching_subscribers_callback_or_channel(memory_fabric):
    a, b = memory_fabric.session(), memory_fabric.session()
    got: queue.Queue[tuple[str, bytes]] = queue.Queue()
    b.declare_subscriber("am/c/station/*", lambda s: got.put((str(s.key_expr), s.payload.to_bytes())))
    channel = b.declare_subscriber("am/c/station/pose", handler=zenoh.handlers.FifoChannel(8))
    own = a.declare_subscriber("am/c/station/pose", handler=zenoh.handlers.FifoChannel(8))
    pub = a.declare_publisher("am/c/station/pose", congestion_control=zenoh.CongestionControl.DROP,
                              reliability=zenoh.Reliability.RELIABLE)
    pub.put(b"p1")
    a.put("am/c/station/state", b"s1")
    a.put("am/c/planner/progress", b"elsewhere")
    assert got.get(timeout=WAIT_S) == ("am/c/station/pose", b"p1")
    assert got.get(timeout=WAIT_S) == ("am/c/station/state", b"s1")
    assert channel.recv().payload.to_bytes() == b"p1" and channel.try_recv() is None
    assert own.recv().payload.to_bytes() == b"p1"           # a session hears itself, as in Zenoh
    channel.undeclare()
    pub.put(b"p2")
    assert memory_fabric.drain()
    assert channel.try_recv() is None and got.get(timeout=WAIT_S) == ("am/c/station/pose", b"p2")
    pub.undeclare()
    with pytest.raises(zenoh.ZError):
        pub.put(b"p3")


def test_liveliness_tokens_queries_and_changes(memory_fabric):
    a, b = memory_fabric.session(), memory_fabric.session()
    a.liveliness().declare_token("am/c1/alive/station")
    planner = a.liveliness().declare_token("am/c1/alive/planner")
    b.liveliness().declare_token("am/c2/alive/station")

    def alive(key: str) -> list[str]:
        return sorted(str(r.ok.key_expr) for r in b.liveliness().get(key, timeout=WAIT_S) if r.ok is not None)
    assert alive("am/c1/alive/*") == ["am/c1/alive/planner", "am/c1/alive/station"]
    changes: queue.Queue[tuple[str, zenoh.SampleKind]] = queue.Queue()
    b.liveliness().declare_subscriber("am/c1/alive/*", lambda s: changes.put((str(s.key_expr), s.kind)),
                                      history=True)
    present = sorted([changes.get(timeout=WAIT_S), changes.get(timeout=WAIT_S)], key=lambda c: c[0])    # first
    assert present == [("am/c1/alive/planner", zenoh.SampleKind.PUT), ("am/c1/alive/station", zenoh.SampleKind.PUT)]
    planner.undeclare()
    assert changes.get(timeout=WAIT_S) == ("am/c1/alive/planner", zenoh.SampleKind.DELETE)
    a.close()                                              # a closed session's tokens go with it
    assert changes.get(timeout=WAIT_S) == ("am/c1/alive/station", zenoh.SampleKind.DELETE)
    assert alive("am/*/alive/*") == ["am/c2/alive/station"]


def test_a_closed_session_refuses_everything_with_zerror(memory_fabric):
    s = memory_fabric.session()
    s.close()
    assert s.is_closed()
    for call in (lambda: s.get("am/x", timeout=1.0), lambda: s.put("am/x", b""),
                 lambda: s.declare_queryable("am/x", print), lambda: s.liveliness()):
        with pytest.raises(zenoh.ZError, match="session closed"):
            call()


def test_the_hub_is_the_sessions_router_so_it_is_linked_at_once(memory_fabric):
    s = memory_fabric.session()
    assert [str(z) for z in s.info.routers_zid()] == [str(memory_fabric.zid)] and s.info.peers_zid() == []
    assert str(s.info.zid()) != str(memory_fabric.zid)
    t0 = time.monotonic()
    assert wait_connected(s, WAIT_S) and time.monotonic() - t0 < 0.1


def test_arguments_zenoh_refuses_are_refused(memory_fabric):
    s = memory_fabric.session()
    with pytest.raises(zenoh.ZError):
        s.get("am//x", timeout=1.0)                          # an empty chunk
    with pytest.raises(TypeError, match="priorty"):
        s.get("am/x", timeout=1.0, priorty=zenoh.Priority.INTERACTIVE_HIGH)
    with pytest.raises(TypeError):
        s.declare_subscriber("am/x", handler=zenoh.handlers.RingChannel(4))
