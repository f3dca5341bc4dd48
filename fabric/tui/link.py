"""The console's link to one cell: telemetry subscriptions read on threads, posted up as messages."""
from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable, Hashable
from typing import Any

from textual.message import Message

from fabric.client import AliveSubscription, Client, Subscription
from fabric.schemas import states
from fabric.tui.joblist import console_jobs
from fabric.tui.messages import HealthReport, JobsListed, Liveliness, ProgramReady, Telemetry
from fabric.wire.errors import FabricError

__all__ = ["CellLink", "STREAMS"]

log = logging.getLogger("fabric.tui")

STREAMS = (("station", "pose"), ("station", "extrusion"), ("station", "temps"), ("station", "state"),
           ("station", "events"), ("supervisor", "jobs"), ("supervisor", "queue"))
# sampled streams: the screen shows at most one message of each per period (s). The robot's pose and the
# extruder at 10 Hz; the temperatures (a graph of the last minute, and their figures) at 2 Hz: each update
# re-renders the graph, and at 10 Hz an idle console spent a fifth of a core on it
THROTTLED = {"pose": 0.1, "extrusion": 0.1, "temps": 0.5}
# ... but a sample that says something new is posted at once: a set point changed (by this console or any
# other client) shows when the station says it, not up to a period later
CHANGED: dict[str, Callable[[Any], Hashable]] = {"temps": lambda t: (t.nozzle_target_c, t.bed_target_c)}
HEALTH_PERIOD_S = 5.0          # how often the console asks the services how they are


class CellLink:
    """Follows one cell for the console. Zenoh callbacks only enqueue (the client's subscriptions); one
    thread per stream decodes and posts :class:`Telemetry`; blocking queries run on their own threads.
    Every message names its cell, so the console drops what a link it closed still posted."""

    def __init__(self, client: Client, post: Callable[[Message], object]) -> None:
        self.client, self.post = client, post
        self.cell = client.keys.cell
        self._stop = threading.Event()
        self._subs: list[Subscription] = []
        self._threads: list[threading.Thread] = []
        self._alive_sub: AliveSubscription | None = None
        self._program_id = ""

    def open(self) -> None:
        for service, topic in STREAMS:
            sub = self.client.subscribe(service, topic)
            self._subs.append(sub)
            self._spawn(self._feed, topic, sub, name=f"tui:{topic}")
        # liveliness changes are posted from the Zenoh callback (posting does not block)
        def alive_changed(name: str, alive: bool) -> None:
            self.post(Liveliness(self.cell, {name: alive}))

        self._alive_sub = self.client.subscribe_alive(alive_changed)
        self._spawn(self._snapshot, name="tui:snapshot")
        self._spawn(self._health_loop, name="tui:health")

    def close(self) -> None:
        self._stop.set()
        for sub in self._subs:
            sub.close()
        if self._alive_sub is not None:
            self._alive_sub.close()
        for t in self._threads:
            t.join(timeout=1.0)

    def _spawn(self, fn: Callable, *args: object, name: str) -> None:
        t = threading.Thread(target=fn, args=args, name=name, daemon=True)
        self._threads.append(t)
        t.start()

    # --- threads ---------------------------------------------------------------

    def _feed(self, topic: str, sub: Subscription) -> None:
        last_post, last_key = 0.0, None
        changed = CHANGED.get(topic)
        while not self._stop.is_set():
            try:
                msg = sub.get(timeout=0.25)
            except queue.Empty:
                continue
            except FabricError as err:
                log.warning("bad %s message: %s", topic, err)
                continue
            if topic in THROTTLED:
                now, key = time.monotonic(), changed(msg) if changed is not None else None
                if now - last_post < THROTTLED[topic] and key == last_key:
                    continue
                last_post, last_key = now, key
            self.post(Telemetry(self.cell, topic, msg))
            if topic == "state" and msg.program_id != self._program_id:
                self._program_id = msg.program_id
                self._spawn(self._fetch_program, msg.program_id, name="tui:program")

    def _health_loop(self) -> None:
        """Each service's own health (ok / degraded and why), asked in one query every few seconds."""
        while not self._stop.is_set():
            try:
                healths = self.client.healths(timeout=1.0)
            except FabricError as err:
                log.info("no health answers: %s", err)
            else:
                degraded = {n: h.reasons if states.Health(h.state) is states.Health.DEGRADED else []
                            for n, h in healths.items()}
                self.post(HealthReport(self.cell, degraded))
            self._stop.wait(HEALTH_PERIOD_S)

    def _snapshot(self) -> None:
        """Snapshot first (then the streams carry the changes): liveliness, state, jobs."""
        self.post(Liveliness(self.cell, self.client.alive(timeout=2.0)))
        try:
            st = self.client.state()
        except FabricError as err:
            log.info("no station state: %s", err)
        else:
            self.post(Telemetry(self.cell, "state", st))
            if st.program_id != self._program_id:
                self._program_id = st.program_id
                self._fetch_program(st.program_id)
        self.refresh_jobs()

    def refresh_jobs(self) -> None:
        """Ask the supervisor for the job list the console shows (blocking: call from a thread)."""
        try:
            self.post(JobsListed(self.cell, console_jobs(self.client)))
        except FabricError as err:
            log.info("no job list: %s", err)

    def _fetch_program(self, program_id: str) -> None:
        from fabric.programs import program_from_artifact
        from fabric.tui.toolpath import Toolpath
        if not program_id:
            self.post(ProgramReady(self.cell, "", None))
            return
        try:
            program = program_from_artifact(self.client.artifact("planner", program_id, timeout=30.0))
            self.post(ProgramReady(self.cell, program_id, Toolpath.from_program(program)))
        except FabricError as err:
            log.warning("program %s not readable: %s", program_id, err)
            self.post(ProgramReady(self.cell, program_id, None))
