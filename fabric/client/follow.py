"""Follow a print to its end: the station's end-of-print event, from history or from the live stream."""
from __future__ import annotations

from fabric import schemas as s
from fabric.client.protocols import Caller

__all__ = ["END_EVENTS", "follow_print"]

END_EVENTS = ("finished", "stopped", "fault")


def follow_print(client: Caller, timeout_s: float | None = None) -> s.Event:
    """Wait for the station's end-of-print event (finished, stopped or fault) and return it.

    Subscribes to the event stream first, then reads the state: a print that is
    no longer running has already ended, so its end event is taken from the last
    50 events of the history; otherwise the next end event on the stream is
    returned. Raises ``queue.Empty`` when ``timeout_s`` passes without an event.
    """
    sub = client.subscribe("station", "events")
    try:
        last = client.call("station", "events", s.EventsQuery(limit=1)).last_seq
        st = client.call("station", "state")
        if not st.state.in_print:
            for ev in reversed(client.call("station", "events", s.EventsQuery(since_seq=max(0, last - 50))).events):
                if ev.kind in END_EVENTS:
                    return ev
        while True:
            ev = sub.get(timeout=timeout_s)
            if ev.kind in END_EVENTS:
                return ev
    finally:
        sub.close()
