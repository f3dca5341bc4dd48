"""Following the station's lossless event stream from where the supervisor left off, in batches.

The supervisor subscribes to the live stream first, then reads the station's
event log from the last event it applied, so nothing falls in between. Events
are handed over in order, in batches of at most ``EVENT_BATCH``; a batch whose
first event is past the next expected number (the station restarted, the link
dropped) sends the follower back to the log.
"""
from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable

from fabric import schemas as s
from fabric.client import Client, Subscription
from fabric.wire.errors import FabricError

__all__ = ["EventFollower", "EVENT_BATCH"]

log = logging.getLogger("fabric.printjobs")
EVENT_BATCH = 500             # events handed over at once, at most
LOG_PAGE = 10_000             # the station's events query answers at most this many


class EventFollower:
    """Feeds ``apply(batch) -> bool`` (False: a gap, read the log again) the events after ``applied()``."""

    def __init__(self, client: Client, live: Subscription, applied: Callable[[], int],
                 apply: Callable[[list[s.Event]], bool], closed: threading.Event) -> None:
        self.client, self.live, self.applied, self.apply, self.closed = client, live, applied, apply, closed

    def run(self) -> None:
        caught_up = False
        while not self.closed.is_set():
            if not caught_up:
                caught_up = self._catch_up()
                if not caught_up:
                    self.closed.wait(1.0)
                    continue
            try:
                batch = [self.live.get(timeout=0.5)]
            except queue.Empty:
                continue
            while len(batch) < EVENT_BATCH:
                try:
                    batch.append(self.live.get(timeout=0))
                except queue.Empty:
                    break
            caught_up = self.apply(batch)

    def _catch_up(self) -> bool:
        """Read the log from the event after the last applied; False when the station cannot be asked."""
        try:
            since = self.applied() + 1
            while True:
                batch = [ev for ev in self.client.events(since).events if ev.seq >= since]
                if batch:
                    self.apply(batch)
                    since = batch[-1].seq + 1
                if len(batch) < LOG_PAGE:
                    return True
        except FabricError as err:
            log.info("cannot read the station's events yet (%s: %s)", err.code, err.message)
            return False
