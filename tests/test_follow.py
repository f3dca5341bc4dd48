"""follow_print against a stand-in station over real in-process Zenoh sessions: history or live stream."""
from __future__ import annotations

import queue
import threading
import time

import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.client.follow import follow_print
from fabric.server.service import Service

pytestmark = pytest.mark.timeout(60)


class StandInStation(Service):
    """Answers ``state`` and ``events`` from fixed values and publishes events when told to."""

    name = "station"
    partial = True

    def __init__(self, session, cell: str, state: str, history: list[s.Event]) -> None:
        super().__init__(session, cell)
        self.state, self.history = state, history
        self.events_out = self.publisher("events", lossless=True)
        self.handle("state", lambda _: s.StationState(state=self.state))
        self.handle("events", lambda q: s.EventList(events=[e for e in self.history if e.seq >= q.since_seq],
                                                    next_seq=len(self.history) + 1,
                                                    last_seq=len(self.history)))


def _event(seq: int, kind: str) -> s.Event:
    return s.Event(seq=seq, t_sim_s=float(seq), kind=kind)


@pytest.fixture
def client(hub, settings):
    with Client.connect(settings) as c:
        yield c


def _station(session, settings, client, state: str, kinds: list[str]) -> StandInStation:
    station = StandInStation(session, settings.cell, state, [_event(i, k) for i, k in enumerate(kinds)])
    station.start()
    client.wait_alive(("station",), deadline_s=10)
    return station


def test_an_ended_print_returns_its_last_end_event_from_history(session, settings, client):
    station = _station(session, settings, client, "idle", ["start", "stopped", "start", "finished", "home"])
    try:
        end = follow_print(client, timeout_s=5)
    finally:
        station.close()
    assert (end.kind, end.seq) == ("finished", 3)


def test_a_running_print_waits_for_the_next_end_event_on_the_stream(session, settings, client):
    station = _station(session, settings, client, "printing", ["finished", "start"])   # an older print's end
    got: list[s.Event] = []
    done = threading.Event()

    def follow() -> None:
        got.append(follow_print(client, timeout_s=20))
        done.set()
    threading.Thread(target=follow, daemon=True).start()
    deadline = time.monotonic() + 20
    seq = 2
    try:
        while not done.wait(0.1):       # published until the follower has subscribed and seen one
            assert time.monotonic() < deadline, "follow_print never returned"
            station.events_out.send(_event(seq, "layer"))
            station.events_out.send(_event(seq + 1, "stopped"))
            seq += 2
    finally:
        station.close()
    assert got[0].kind == "stopped" and got[0].seq >= 3


def test_no_end_event_within_the_timeout_raises_empty(session, settings, client):
    station = _station(session, settings, client, "paused", ["start", "pause"])
    try:
        with pytest.raises(queue.Empty):
            follow_print(client, timeout_s=0.3)
    finally:
        station.close()
