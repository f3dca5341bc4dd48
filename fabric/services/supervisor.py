"""Supervisor service: the cell's liveliness, and print jobs from submission to the end of the print.

A print job is the paper's one-click path made explicit and durable. A submit
is acknowledged once its record and its file are on disk (``jobs.sqlite``,
and the file as an artifact pinned by the job). A worker prepares the queued
jobs in order (slice unless it is G-code, plan, check collisions:
:mod:`fabric.printjobs.prepare`), each stage surviving restarts of the
service it calls. A prepared job at the head of the queue is loaded on the
station when the station has no job and the plate is clear, and started if it
was submitted with ``start``; once a print has begun on the plate, the next
job waits for the operator to confirm the plate is clear (``job_next``), as a
printer host's queue does. The job then follows the station's lossless event
stream (:mod:`fabric.printjobs.events`): printing, paused, finished, stopped,
failed or interrupted, with timestamps, durations, filament and volume. The
last event applied is stored with the records, so a restarted supervisor
catches up from the station's event log exactly where it stopped; jobs that
were being prepared are prepared again.
"""
from __future__ import annotations

import argparse
import queue
import threading
import time
import uuid
from pathlib import Path

import zenoh

from fabric import schemas as s
from fabric.client import Client
from fabric.wire.config import service_data_dir
from fabric.wire.errors import FabricError, NotFound, StateError, ValidationError
from fabric.wire.keys import SERVICES, parse_alive
from fabric.printjobs.events import apply_event, job_id_of_event
from fabric.printjobs.prepare import PrepareCancelled, Preparer
from fabric.programs import content_id
from fabric.server.service import Service
from fabric.store.jobs import JobStore

__all__ = ["SupervisorService", "build", "add_arguments"]

WAITING_STATES = ("queued", "slicing", "planning", "checking")
STATION_FREE = ("idle", "ready", "stopped", "fault")
MODEL_MEDIA = {"model": "application/octet-stream", "gcode": "text/x-gcode"}
WAITING_TEXT = {"plate": "prepared: confirm the plate is clear (job next)",
                "station": "prepared: waiting for the station to be free",
                "queue": "prepared: waiting behind the jobs ahead of it"}


class SupervisorService(Service):
    name = "supervisor"

    def __init__(self, session: zenoh.Session, cell: str, data_dir: Path | None = None) -> None:
        super().__init__(session, cell, data_dir)
        self.client = Client(session, cell)
        self.store = JobStore(self.data_dir / "jobs.sqlite")
        self.lock = threading.RLock()                     # one writer of job records at a time
        self.wake = threading.Event()                     # something to prepare or to load
        self.pub_jobs = self.publisher("jobs", lossless=True)
        self.preparer = Preparer(self.client, self.artifacts, self._save, self.closed)
        self._alive: dict[str, float] = {}                # service -> since (wall time)
        self._alive_lock = threading.Lock()
        self._live: queue.Queue[tuple[str, str]] = queue.Queue()
        self.handle("status", self.on_status)
        self.handle("submit", self.on_submit)
        self.handle("job", lambda q: self.store.get(q.job_id))
        self.handle("jobs", self.on_jobs)
        self.handle("job_remove", self.on_job_remove)
        self.handle("job_move", self.on_job_move)
        self.handle("job_next", self.on_job_next)
        self._requeue_interrupted_preparations()

    def start(self) -> None:
        # liveliness and station events: the callbacks only enqueue; workers apply and log
        self._live_sub = self.session.liveliness().declare_subscriber(
            self.keys.alive_all(), lambda smp: self._live.put((str(smp.kind), str(smp.key_expr))), history=True)
        self._events = self.client.subscribe("station", "events")
        self._workers = [threading.Thread(target=target, name=f"supervisor:{name}", daemon=True)
                         for target, name in ((self._track, "liveliness"), (self._prepare_loop, "prepare"),
                                              (self._follow_loop, "follow"))]
        for t in self._workers:
            t.start()
        super().start()
        self.wake.set()

    def close(self) -> None:
        super().close()                      # sets ``closed``: the workers finish what they are doing
        self.wake.set()
        for t in getattr(self, "_workers", []):
            t.join(timeout=5.0)
        if hasattr(self, "_live_sub"):
            self._live_sub.undeclare()
            self._events.close()
        self.store.close()

    # --- records --------------------------------------------------------------------

    def _save(self, rec: s.JobRecord, last_event_seq: int | None = None) -> None:
        """Persist a changed record, then publish it (lossless ``jobs`` topic)."""
        rec.updated_s = time.time()
        with self.lock:
            self.store.save(rec, last_event_seq=last_event_seq)
        self.pub_jobs.send(rec)

    def _requeue_interrupted_preparations(self) -> None:
        """Jobs this supervisor was preparing when it stopped are prepared again from the start."""
        for rec in self.store.all():
            if rec.state in ("slicing", "planning", "checking"):
                rec.state, rec.prepared = "queued", False
                rec.stage = "queued again: the supervisor restarted while preparing it"
                self.log.info("job %s: %s", rec.job_id, rec.stage)
                self.store.save(rec)

    def _waiting(self) -> list[s.JobRecord]:
        return [r for r in self.store.all() if r.state in WAITING_STATES]

    def _on_station(self) -> s.JobRecord | None:
        return next((r for r in self.store.all() if r.state in s.ON_STATION_JOB_STATES), None)

    # --- handlers -------------------------------------------------------------------

    def on_status(self, _: s.Empty) -> s.FabricStatus:
        # who is alive: the hub's answer now; since when: what the liveliness subscriber tracked
        now = self.client.alive(timeout=2.0)
        now["supervisor"] = True
        with self._alive_lock:
            since = dict(self._alive)
        since.setdefault("supervisor", self.started_s)
        infos = [s.ServiceInfo(name=n, alive=now[n], since_s=since.get(n, 0.0) if now[n] else 0.0) for n in SERVICES]
        records = self.store.all()
        current = self._on_station() or (max(records, key=lambda r: r.updated_s) if records else None)
        return s.FabricStatus(cell=self.keys.cell, services=infos, job=current)

    def on_submit(self, req: s.JobSubmit) -> s.JobAccepted:
        if not req.model:
            raise ValidationError("the submitted file is empty", field="model")
        art = s.Artifact(artifact_id=content_id(req.model), name=req.filename, media_type=MODEL_MEDIA[req.source],
                         data=req.model)
        job_id = uuid.uuid4().hex[:12]
        self.artifacts.put(art)
        self.artifacts.pin(art.artifact_id, job_id)
        now = time.time()
        rec = s.JobRecord(job_id=job_id, filename=req.filename, source=req.source, profile=req.profile,
                          backend=req.backend, model_id=art.artifact_id, overrides=dict(req.overrides),
                          start=req.start, rtf=req.rtf, state="queued", stage="queued", created_s=now,
                          updated_s=now)
        with self.lock:
            self.store.add(rec)
        self.pub_jobs.send(rec)
        self.log.info("job %s queued: %s (%s)", job_id, req.filename, req.source)
        self.wake.set()
        return s.JobAccepted(job_id=job_id, kind="print")

    def on_jobs(self, _: s.Empty) -> s.JobList:
        return s.JobList(jobs=self.store.all())

    def on_job_remove(self, req: s.JobQuery) -> s.Ack:
        with self.lock:
            rec = self.store.get(req.job_id)
            if rec.state in s.ON_STATION_JOB_STATES:
                raise StateError(f"job {rec.job_id} is {rec.state} on the station: stop it first",
                                 state=rec.state, command="job remove")
            self.store.remove(rec.job_id)
        self._release(rec)
        return s.Ack(ok=True, message=f"removed job {rec.job_id} ({rec.filename})", state=rec.state)

    def on_job_move(self, req: s.JobMove) -> s.JobList:
        with self.lock:
            self.store.get(req.job_id)
            self.store.move(req.job_id, req.position, [r.job_id for r in self._waiting()])
        self.wake.set()
        return s.JobList(jobs=self.store.all())

    def on_job_next(self, _: s.Empty) -> s.Ack:
        """The operator confirms the plate is clear: load the next prepared job and start it (or the
        next one submitted, if none waits)."""
        with self.lock:
            busy = self._on_station()
            if busy is not None and busy.state != "loaded":
                raise StateError(f"job {busy.job_id} is {busy.state} on the station", state=busy.state,
                                 command="job next")
            self.store.set_plate_clear(True)
            waiting = self._waiting()
            if not waiting:
                return s.Ack(ok=True, message="plate marked clear; no job is waiting: the next one submitted "
                                              "with --start starts at once", state="")
            head = waiting[0]
            head.start = True
            self.store.save(head)
        if not head.prepared:
            self.wake.set()
            return s.Ack(ok=True, message=f"plate marked clear; job {head.job_id} starts once prepared "
                                          f"({head.state})", state=head.state)
        self._load_next()
        head = self.store.get(head.job_id)
        return s.Ack(ok=True, message=f"plate marked clear; job {head.job_id} ({head.filename}) {head.state}",
                     state=head.state)

    # --- preparing and loading ------------------------------------------------------

    def _prepare_loop(self) -> None:
        while not self.closed.is_set():
            self.wake.wait(timeout=1.0)
            self.wake.clear()
            try:
                while not self.closed.is_set():
                    todo = next((r for r in self._waiting() if r.state == "queued" and not r.prepared), None)
                    if todo is None:
                        break
                    self.preparer.prepare(todo)
                    self._release_if_final(todo)
                self._load_next()
            except PrepareCancelled:
                return
            except FabricError as err:                   # e.g. the station is away: try again on the next wake
                self.log.warning("job queue: %s: %s", err.code, err.message)

    def _load_next(self) -> None:
        """Load the head of the queue when it is prepared, the station has no job and the plate is clear;
        otherwise say on each prepared job what it waits for."""
        with self.lock:
            waiting = self._waiting()
            if not waiting:
                return
            head = waiting[0]
            for rec in waiting[1:]:
                self._wait_for(rec, "queue")
            if not head.prepared:
                return
            if self._on_station() is not None:
                self._wait_for(head, "station")
                return
            if not self.store.plate_clear():
                self._wait_for(head, "plate")
                return
        station = self.client.state()
        if station.state not in STATION_FREE:
            self.log.info("job %s waits: the station is %s", head.job_id, station.state)
            self._wait_for(head, "station")
            return
        try:
            self.client.load(head.program_id, job_id=head.job_id)
        except NotFound as err:                 # its program is gone (never acknowledged durably): plan again
            self.log.warning("job %s: %s; preparing it again", head.job_id, err.message)
            head.prepared, head.waiting_for, head.program_id = False, "", ""
            head.stage = f"queued again: {err.message}"
            self._save(head)
            self.wake.set()
            return
        head.state, head.stage, head.waiting_for = "loaded", "loaded on the station", ""
        self._save(head)
        self.log.info("job %s loaded on the station", head.job_id)
        if head.start:
            self.store.set_plate_clear(False)
            self.client.start(rtf=head.rtf)

    def _wait_for(self, rec: s.JobRecord, what: str) -> None:
        """Record (once) what a prepared job waits for."""
        if not rec.prepared or rec.waiting_for == what:
            return
        rec.waiting_for = what
        rec.stage = WAITING_TEXT[what]
        self._save(rec)

    def _release(self, rec: s.JobRecord) -> None:
        """The job no longer needs its artifacts: release its pins everywhere (best effort, logged)."""
        self.artifacts.unpin(rec.job_id)
        for service in ("slicer", "planner"):
            try:
                self.client.unpin(service, rec.job_id)
            except FabricError as err:
                self.log.warning("could not release job %s's pins at %s: %s", rec.job_id, service, err.message)

    def _release_if_final(self, rec: s.JobRecord) -> None:
        if rec.state in s.FINAL_JOB_STATES:
            self._release(rec)

    # --- following the station ------------------------------------------------------

    def _follow_loop(self) -> None:
        """Apply the station's events to the jobs: first the log since the last one applied, then the
        live stream (subscribed before the log was read, so nothing falls in between)."""
        caught_up = False
        self._seen = self.store.last_event_seq()
        self._seen_saved_s = time.monotonic()
        while not self.closed.is_set():
            if not caught_up:
                caught_up = self._catch_up()
                if not caught_up:
                    self.closed.wait(1.0)
                    continue
            try:
                ev = self._events.get(timeout=0.5)
            except queue.Empty:
                continue
            if ev.seq <= self._seen:
                continue
            if ev.seq > self._seen + 1:                  # a gap (e.g. the station restarted): read the log
                caught_up = False
                continue
            self._apply(ev)

    def _catch_up(self) -> bool:
        try:
            since = self._seen + 1
            while True:
                batch = self.client.events(since).events
                for ev in batch:
                    if ev.seq >= since:
                        self._apply(ev)
                        since = ev.seq + 1
                if len(batch) < 10_000:
                    return True
        except FabricError as err:
            self.log.info("cannot read the station's events yet (%s: %s)", err.code, err.message)
            return False

    def _apply(self, ev: s.Event) -> None:
        """Apply one event. A record it changes is saved with the event's number (never applied twice);
        the number of events that change nothing is saved at most every second (replaying those
        after a restart changes nothing either)."""
        ended = None
        with self.lock:
            rec = self._record_of(job_id_of_event(ev))
            self._seen = ev.seq
            if rec is not None and apply_event(rec, ev, time.time()):
                self._save(rec, last_event_seq=ev.seq)
                self._seen_saved_s = time.monotonic()
                if ev.kind == "started":
                    self.store.set_plate_clear(False)
                if rec.state in s.FINAL_JOB_STATES:
                    ended = rec
            elif time.monotonic() - self._seen_saved_s > 1.0:
                self.store.save(last_event_seq=ev.seq)
                self._seen_saved_s = time.monotonic()
        if ended is not None:                  # asking other services happens outside the lock
            self._release(ended)
            self.wake.set()

    def _record_of(self, job_id: str) -> s.JobRecord | None:
        if not job_id:
            return None
        try:
            return self.store.get(job_id)
        except NotFound:                    # a job loaded by hand (fabric-cli load), not through the queue
            return None

    # --- liveliness -------------------------------------------------------------------

    def _track(self) -> None:
        while not self.closed.is_set():
            try:
                kind, key = self._live.get(timeout=0.5)
            except queue.Empty:
                continue
            _, svc = parse_alive(key)
            with self._alive_lock:
                if kind.endswith("PUT"):
                    self._alive[svc] = time.time()
                    self.log.info("service %s is alive", svc)
                else:
                    self._alive.pop(svc, None)
                    self.log.warning("service %s is gone", svc)
            if svc == "station" and kind.endswith("PUT"):
                self.wake.set()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The supervisor has no options of its own."""


def build(session: zenoh.Session, cell: str, options: argparse.Namespace) -> SupervisorService:
    return SupervisorService(session, cell, service_data_dir(options.data_dir, cell, "supervisor"))

