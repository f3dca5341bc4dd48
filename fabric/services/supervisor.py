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

Job records have one writer (:mod:`fabric.server.writer`): every transition,
from a command, the preparer, the load sequence or a station event, is a step
that reads the record as it is now, changes it and saves it; calls to other
services run between steps, never inside one. The writer's fields are
:class:`~fabric.server.writer.Owned` and the job store refuses a change from
another thread: what a comment used to say, the code now checks.
"""
from __future__ import annotations

import argparse
import queue
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import zenoh

from fabric import schemas as s
from fabric.client import Client
from fabric.printjobs.events import apply_event, job_id_of_event
from fabric.printjobs.follower import EventFollower
from fabric.printjobs.live import LIVE_PERIOD_S, apply_live
from fabric.printjobs.prepare import PrepareCancelled, Preparer
from fabric.printjobs.queue import PREPARER_FIELDS, WAITING_STATES, WAITING_TEXT, next_to_load
from fabric.programs import content_id
from fabric.schemas.states import PrintJob
from fabric.server.service import Service
from fabric.server.writer import Owned, Writer
from fabric.services.supervisor_files import LibraryCommands
from fabric.store.jobs import JobStore
from fabric.wire import codec
from fabric.wire.config import service_data_dir
from fabric.wire.errors import BadRequest, DiskFull, FabricError, NotFound, StateError, ValidationError
from fabric.wire.keys import SERVICES, parse_alive

__all__ = ["SupervisorService", "build", "add_arguments"]

STEP_TIMEOUT_S = 4.0          # a change not begun by then is dropped (under the 5 s a caller waits)
LOAD_WAIT_S = 20.0            # "job next" waits this long for a load under way (its caller waits 60 s)
T = TypeVar("T")


class SupervisorService(Service):
    name = "supervisor"
    # the writer's: read or changed in its steps only
    _loading: Owned[str] = Owned()                        # the job being loaded on the station
    _plate_epoch: Owned[int] = Owned()                    # counts the operator's "plate clear"
    _seen: Owned[int] = Owned()                           # the last station event applied
    _seen_saved_s: Owned[float] = Owned()                 # when that number was last saved

    def __init__(self, session: zenoh.Session, cell_id: str, data_dir: Path | None = None) -> None:
        super().__init__(session, cell_id, data_dir)
        self.client = Client(session, cell_id)
        self.writer = Writer(self.name)                   # the one writer of job records and the plate
        self.store = JobStore(self.data_dir / "jobs.sqlite", self.writer)
        self.wake = threading.Event()                     # something to prepare or to load
        self.pub_jobs = self.publisher("jobs", lossless=True)
        self.pub_queue = self.publisher("queue", lossless=True)
        self.preparer = Preparer(self.client, self.artifacts, self._save_prepared, self.closed)
        self._loading = ""
        self._plate_epoch = 0
        self._seen = self.store.last_event_seq()
        self._seen_saved_s = time.monotonic()
        self._alive: dict[str, float] = {}                # service -> since (wall time)
        self._alive_lock = threading.Lock()
        self._live: queue.Queue[tuple[str, str]] = queue.Queue()
        self._station_state: bytes | None = None          # the station's last state (for the live figures)
        self.handle("status", self.on_status)
        self.handle("submit", self.on_submit)
        self.handle("job", lambda q: self.store.get(q.job_id))
        self.handle("jobs", self.on_jobs)
        self.handle("job_remove", self.on_job_remove)
        self.handle("job_move", self.on_job_move)
        self.handle("job_next", self.on_job_next)
        self.library = LibraryCommands(self.data_dir, self.artifacts, self.name, self._step, self.log)
        self.handle("files", self.library.on_files)
        self.handle("file", lambda q: self.library.library.get(q.file_id))
        self.handle("file_add", self.library.on_file_add)
        self.handle("file_remove", self.library.on_file_remove)
        self.handle("upload", self.library.on_upload)       # a large file to submit, in pieces
        self._requeue_interrupted_preparations()

    def start(self) -> None:
        # liveliness and station events: the callbacks only enqueue; workers apply and log
        self._live_sub = self.session.liveliness().declare_subscriber(
            self.keys.alive_all(), lambda smp: self._live.put((str(smp.kind), str(smp.key_expr))), history=True)
        self._events = self.client.subscribe("station", "events")
        self._state_sub = self.session.declare_subscriber(          # keeps only the last one
            self.keys.topic("station", "state"), lambda smp: setattr(self, "_station_state", smp.payload.to_bytes()))
        self._workers = [threading.Thread(target=target, name=f"supervisor:{name}", daemon=True)
                         for target, name in ((lambda: self.writer.run(self.closed), "writer"),
                                              (self._track, "liveliness"), (self._prepare_loop, "prepare"),
                                              (self._follow_events, "follow"), (self._live_figures, "live"))]
        for t in self._workers:
            t.start()
        super().start()
        self.wake.set()

    def close(self) -> None:
        super().close()                      # sets ``closed``: the workers finish what they are doing
        self.preparer.stop()                 # a preparation waiting on a slicer or a planner stops waiting
        self.wake.set()
        self.writer.close()                  # a worker asking for a step now hears at once that there is none
        for t in getattr(self, "_workers", []):
            t.join(timeout=5.0)
        if hasattr(self, "_live_sub"):
            self._live_sub.undeclare()
            self._events.close()
            self._state_sub.undeclare()
        self.store.close()
        self.library.close()

    # --- records: changed only by steps of the writer ---------------------------------

    def _step(self, fn: Callable[[], T]) -> T:
        return self.writer.call(fn, timeout_s=STEP_TIMEOUT_S)

    def _save(self, rec: s.JobRecord, last_event_seq: int | None = None) -> None:
        """Persist a changed record, then publish it (lossless ``jobs`` topic). On the writer only.

        The library's entry is noted first: a client that reads the record's new state (``job``, the topic)
        then finds its file's entry showing it too (reads do not wait for the writer)."""
        rec.updated_s = time.time()
        self.library.job_changed(rec)
        self.store.save(rec, last_event_seq=last_event_seq)
        self.pub_jobs.send(rec)

    def _save_prepared(self, prepared: s.JobRecord) -> None:
        """The preparer's progress: its own fields are written onto the record as it is now (a ``job next``
        meanwhile keeps its ``start``); a job removed or moved on meanwhile cancels the preparation."""
        def step() -> None:
            try:
                rec = self.store.get(prepared.job_id)
            except NotFound:
                raise PrepareCancelled(prepared.job_id) from None
            if not rec.state.waiting or rec.prepared:
                raise PrepareCancelled(prepared.job_id)
            for name in PREPARER_FIELDS:
                setattr(rec, name, getattr(prepared, name))
            self._save(rec)
        self._step(step)

    def _requeue_interrupted_preparations(self) -> None:
        """Jobs this supervisor was preparing when it stopped are prepared again from the start (before
        the writer runs: nothing else touches the store yet)."""
        for rec in self.store.in_states(("slicing", "planning", "checking")):
            rec.state, rec.prepared = PrintJob.QUEUED, False
            rec.stage = "queued again: the supervisor restarted while preparing it"
            self.log.info("job %s: %s", rec.job_id, rec.stage)
            self.store.save(rec)

    def _queue_changed(self, kind: str, job_id: str) -> None:
        """(Writer) Say on ``supervisor/queue`` that the queue changed, with the waiting queue as it is now."""
        self.pub_queue.send(s.QueueChange(kind=kind, job_id=job_id, waiting=[r.job_id for r in self._waiting()]))

    def _waiting(self) -> list[s.JobRecord]:
        return self.store.in_states(WAITING_STATES)

    def _on_station(self) -> s.JobRecord | None:
        on = self.store.in_states(s.ON_STATION_JOB_STATES)
        return on[0] if on else None

    # --- handlers -------------------------------------------------------------------

    def on_status(self, _: s.Empty) -> s.FabricStatus:
        # who is alive: the hub's answer now; since when: what the liveliness subscriber tracked; how each
        # is: its own health, all asked in one query
        now = self.client.alive(timeout=2.0)
        now["supervisor"] = True
        healths = self.client.healths(timeout=1.0)
        healths[self.name] = self.health.report()
        with self._alive_lock:
            since = dict(self._alive)
        since.setdefault("supervisor", self.started_s)
        infos = []
        for n in SERVICES:
            h = healths.get(n) if now[n] else None
            infos.append(s.ServiceInfo(name=n, alive=now[n], since_s=since.get(n, 0.0) if now[n] else 0.0,
                                       health=h.state if h else "", reasons=list(h.reasons) if h else []))
        current = self._on_station() or self.store.latest()
        return s.FabricStatus(cell=self.keys.cell, services=infos, job=current,
                              station_cell=self.client.station_cell() if now["station"] else None,
                              robot=self.client.station_robot() if now["station"] else None)

    def on_submit(self, req: s.JobSubmit) -> s.JobAccepted:
        """Queue a print job. ``source`` not given is taken from the file name (``s.pipeline.source_of``), here
        at the boundary, so a client that sends a ``.gcode`` without it is understood (or refused at once)."""
        sub = self.library.submission(req)          # its bytes, or a library file's
        source = sub.source
        if source == "gcode" and req.overrides:   # G-code is not sliced: a profile key would be kept and ignored
            raise ValidationError(f"a G-code job is not sliced: the profile keys {sorted(req.overrides)} would change "
                                  f"nothing; the filament's diameter is filament_diameter_mm (job submit "
                                  f"--filament-diameter)", field="overrides")
        if req.layers != "planar" and source == "gcode":      # a multi-axis file says so in its first line
            raise ValidationError(f"a G-code job is not sliced: layers {req.layers!r} would change nothing (G-code "
                                  f"in the multi-axis dialect states its nozzle axes itself)", field="layers")
        if req.layers == "curved" and req.backend != "builtin":
            raise ValidationError(f"curved layers are sliced by the built-in slicer only, not {req.backend!r}",
                                  field="layers", backend=req.backend)
        sub = self.library.keep(sub)                # on disk (content-addressed) and in the library
        job_id = uuid.uuid4().hex[:12]
        model_id = content_id(sub.data)
        self.artifacts.pin(model_id, job_id)
        now = time.time()
        rec = s.JobRecord(job_id=job_id, filename=sub.filename, source=source, profile=req.profile,
                          backend=req.backend, model_id=model_id, overrides=dict(req.overrides), layers=req.layers,
                          start=req.start, rtf=req.rtf, state=PrintJob.QUEUED, stage="queued", created_s=now,
                          updated_s=now, filament_diameter_mm=req.filament_diameter_mm)

        def step() -> None:
            self.store.add(rec)
            self.pub_jobs.send(rec)
            self._queue_changed("submitted", job_id)
            self.library.job_made(sub.file_id, rec)
        self._step(step)
        self.log.info("job %s queued: %s (%s, library file %s)", job_id, sub.filename, source, sub.file_id)
        self.wake.set()
        return s.JobAccepted(job_id=job_id, kind="print")

    def on_jobs(self, req: s.JobsQuery) -> s.JobList:
        jobs, total = self.store.page(req.offset, req.limit, req.states)
        return s.JobList(jobs=jobs, total=total, offset=req.offset)

    def on_job_remove(self, req: s.JobQuery) -> s.Ack:
        def step() -> s.JobRecord:
            rec = self.store.get(req.job_id)
            if rec.state.on_station or rec.job_id == self._loading:
                state = rec.state if rec.state.on_station else "loading"
                raise StateError(f"job {rec.job_id} is {state} on the station: stop it first",
                                 state=state, command="job remove")
            self.store.remove(rec.job_id)
            self._queue_changed("removed", rec.job_id)
            return rec
        rec = self._step(step)
        self.preparer.stop(rec.job_id)       # being prepared: it stops, and cancels the slicing or planning it started
        self._release(rec)
        return s.Ack(ok=True, message=f"removed job {rec.job_id} ({rec.filename})", state=rec.state)

    def on_job_move(self, req: s.JobMove) -> s.JobList:
        def step() -> None:
            self.store.get(req.job_id)
            self.store.move(req.job_id, req.position, [r.job_id for r in self._waiting()])
            self._queue_changed("moved", req.job_id)
        self._step(step)
        self.wake.set()
        jobs, total = self.store.page(0, 100)
        return s.JobList(jobs=jobs, total=total)

    def on_job_next(self, _: s.Empty) -> s.Ack:
        """The operator confirms the plate is clear: the station is told (it owns the part on the plate and
        refuses while a print is on), then the next prepared job is loaded, and started only if it was
        submitted with ``start`` (its record is not changed: a job loaded without it waits for the operator's
        ``start``, as the submitter asked)."""
        self.client.clear_plate()

        def step() -> s.JobRecord | None:
            busy = self._on_station()
            if busy is not None and busy.state != PrintJob.LOADED:
                raise StateError(f"job {busy.job_id} is {busy.state} on the station", state=busy.state,
                                 command="job next")
            self.store.set_plate_clear(True)
            self._plate_epoch += 1                        # a load that read the plate before this one retries
            waiting = self._waiting()
            return waiting[0] if waiting else None
        head = self._step(step)
        if head is None:
            return s.Ack(ok=True, message="plate marked clear; no job is waiting: the next one submitted "
                                          "is loaded once prepared", state="")
        then = "started" if head.start else "loaded (start it with fabric-cli start)"
        if not head.prepared:
            self.wake.set()
            return s.Ack(ok=True, message=f"plate marked clear; job {head.job_id} is {then} once prepared "
                                          f"({head.state})", state=head.state)
        self._load_now()
        try:
            head = self.store.get(head.job_id)
        except NotFound:                                  # removed meanwhile by another operator
            return s.Ack(ok=True, message=f"plate marked clear; job {head.job_id} was removed meanwhile",
                         state="")
        hint = "" if head.start else " (submitted without start: start it with fabric-cli start once loaded)"
        started = head.start and head.state == PrintJob.LOADED           # its start was sent
        now = "loaded and started" if started else head.state
        return s.Ack(ok=True, message=f"plate marked clear; job {head.job_id} ({head.filename}) {now}{hint}",
                     state=head.state)

    # --- preparing and loading ------------------------------------------------------

    def _prepare_loop(self) -> None:
        while not self.closed.is_set():
            self.wake.wait(timeout=1.0)
            self.wake.clear()
            try:
                while not self.closed.is_set():
                    todo = next((r for r in self._waiting() if r.state == PrintJob.QUEUED and not r.prepared), None)
                    if todo is None:
                        break
                    try:
                        self.preparer.prepare(todo)
                    except PrepareCancelled:
                        if self.closed.is_set():
                            return
                        self.log.info("job %s: preparation cancelled (removed or changed meanwhile)", todo.job_id)
                        continue
                    self._release_if_final(todo)
                self._load_next()
            except FabricError as err:                   # e.g. the station is away: try again on the next wake
                self.log.warning("job queue: %s: %s", err.code, err.message)

    def _load_now(self, wait_s: float = LOAD_WAIT_S) -> None:
        """Load the head of the queue now; a load the loop has under way is waited for (bounded) first, so that
        the operator's ``job next`` answers with what it did rather than "queued"."""
        end = time.monotonic() + wait_s
        while not self._load_next() and time.monotonic() < end and not self.closed.is_set():
            time.sleep(0.05)

    def _load_next(self) -> bool:
        """Load the head of the queue when it is prepared, the station has no job and the plate is clear;
        otherwise say on each prepared job what it waits for. One load at a time: the writer marks the job
        being loaded, the station is asked outside it, and the record is changed in a second step from the
        record as it is then (a ``job next`` meanwhile is honoured). False: another load was under way."""
        busy, head, epoch = self._step(self._pick_for_loading)
        if head is None:
            return not busy
        try:
            station = self.client.state()
            if not station.plate_clear:                   # the station owns the part on the plate
                self.log.info("job %s waits: the plate holds a part (%.0f mm3)", head.job_id, station.plate_mm3)

                def plate_taken() -> None:
                    if self._plate_epoch != epoch:        # the operator cleared it since we asked: look again
                        self.wake.set()
                        return
                    self.store.set_plate_clear(False)
                    self._wait_for(self.store.get(head.job_id), "plate")
                self._step(plate_taken)
                return True
            if not station.state.free:
                self.log.info("job %s waits: the station is %s", head.job_id, station.state)
                self._step(lambda: self._wait_for(self.store.get(head.job_id), "station"))
                return True
            try:
                self.client.load(head.program_id, job_id=head.job_id)
            except (DiskFull, BadRequest) as err:  # a load that cannot succeed is not tried again: the job fails
                self.log.warning("job %s cannot be loaded: %s: %s", head.job_id, err.code, err.message)
                failure = err
                self._step(lambda: self._fail(head.job_id, failure))
                self._release_if_final(head)
                self.wake.set()
                return True
            except StateError as err:             # the station is busy after all (e.g. a stop's lift): wait
                self.log.info("job %s waits: %s", head.job_id, err.message)
                self._step(lambda: self._wait_for(self.store.get(head.job_id), "station"))
                return True
            except NotFound as err:             # its program is gone (never acknowledged durably): plan again
                self.log.warning("job %s: %s; preparing it again", head.job_id, err.message)
                why = err.message
                self._step(lambda: self._prepare_again(head.job_id, why))
                self.wake.set()
                return True
            start, rtf = self._step(lambda: self._loaded(head.job_id))
            self.log.info("job %s loaded on the station", head.job_id)
            if start:
                self.client.start(rtf=rtf)
            return True
        finally:
            self._step(self._done_loading)

    def _pick_for_loading(self) -> tuple[bool, s.JobRecord | None, int]:
        """(Writer) (another load is under way, the job to load now marked as being loaded or None, the plate
        epoch it was picked in)."""
        if self._loading:
            return True, None, self._plate_epoch
        decision = next_to_load(self._waiting(), self._on_station(), self.store.plate_clear())
        for rec, what in decision.waits:
            self._wait_for(rec, what)
        if decision.load is not None:
            self._loading = decision.load.job_id
        return False, decision.load, self._plate_epoch

    def _loaded(self, job_id: str) -> tuple[bool, float]:
        """(Writer) The station took the job: record it, and whether to start it now (as the record says now)."""
        rec = self.store.get(job_id)
        rec.state, rec.stage, rec.waiting_for = PrintJob.LOADED, "loaded on the station", ""
        self._save(rec)
        if rec.start:
            self.store.set_plate_clear(False)
        return rec.start, rec.rtf

    def _fail(self, job_id: str, err: FabricError) -> None:
        """(Writer) The job failed with a typed error (its code and message are its reason)."""
        rec = self.store.get(job_id)
        wire = err.to_wire()
        rec.state, rec.reason, rec.stage, rec.ended_s = PrintJob.FAILED, f"{err.code}: {err.message}", "failed", \
            time.time()
        rec.error = s.ErrorReply(code=wire["code"], message=wire["message"], details=wire["details"])
        self._save(rec)

    def _prepare_again(self, job_id: str, why: str) -> None:
        rec = self.store.get(job_id)
        rec.prepared, rec.waiting_for, rec.program_id = False, "", ""
        rec.stage = f"queued again: {why}"
        self._save(rec)

    def _done_loading(self) -> None:
        self._loading = ""

    def _wait_for(self, rec: s.JobRecord, what: str) -> None:
        """(Writer) Record (once) what a prepared job waits for."""
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
        try:
            now = self.store.get(rec.job_id)
        except NotFound:
            return
        if now.state.ended:
            self._release(now)

    # --- following the station ------------------------------------------------------

    def _follow_events(self) -> None:
        EventFollower(self.client, self._events, lambda: self._step(lambda: self._seen), self._apply_batch,
                      self.closed).run()

    def _apply_batch(self, events: list[s.Event]) -> bool:
        """Apply events in order (one writer step); False when a gap shows the log must be read first."""
        ended, gap = self._step(lambda: self._apply_in_writer(events))
        for rec in ended:                  # asking other services happens outside the writer
            self._release(rec)
        if ended or any(ev.kind == "plate_cleared" for ev in events):
            self.wake.set()
        return not gap

    def _apply_in_writer(self, events: list[s.Event]) -> tuple[list[s.JobRecord], bool]:
        """(Writer) Apply each event once. A record it changes is saved with the event's number (never
        applied twice); the number of events that change nothing is saved at most every second (replaying
        those after a restart changes nothing either)."""
        ended: list[s.JobRecord] = []
        for ev in events:
            if ev.seq <= self._seen:
                continue
            if ev.seq > self._seen + 1:                  # a gap (e.g. the station restarted): read the log
                return ended, True
            rec = self._record_of(job_id_of_event(ev))
            self._seen = ev.seq
            if ev.kind == "plate_cleared":                 # the station's word on the plate (started: taken)
                self.store.set_plate_clear(True)
            if rec is not None and apply_event(rec, ev, time.time()):
                self._save(rec, last_event_seq=ev.seq)
                self._seen_saved_s = time.monotonic()
                if ev.kind == "started":
                    self.store.set_plate_clear(False)
                if rec.state.ended:
                    ended.append(rec)
            elif time.monotonic() - self._seen_saved_s > 1.0:
                self.store.save(last_event_seq=ev.seq)
                self._seen_saved_s = time.monotonic()
        return ended, False

    def _live_figures(self) -> None:
        """Every LIVE_PERIOD_S during a print, the printing job's record takes the station's last state's
        figures (progress, volume, layer, time so far: :mod:`fabric.printjobs.live`), one writer step."""
        while not self.closed.wait(LIVE_PERIOD_S):
            data, self._station_state = self._station_state, None
            if data is None:
                continue
            try:
                st = codec.decode(data, s.StationState)
            except FabricError:
                continue
            if not st.state.printing or not st.job_id:
                continue

            def step(st: s.StationState = st) -> None:
                rec = self._record_of(st.job_id)
                if rec is not None and apply_live(rec, st, time.time()):
                    self._save(rec)
            try:
                self._step(step)
            except FabricError as err:                   # busy: the next period tries again
                self.log.debug("live figures of job %s: %s", st.job_id, err.message)

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
                elif svc != self.name:                   # its own token goes as it closes: nothing to report
                    self._alive.pop(svc, None)
                    self.log.warning("service %s is gone", svc)
            if svc == "station" and kind.endswith("PUT"):
                self.wake.set()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The supervisor has no options of its own."""


def build(session: zenoh.Session, cell: str, options: argparse.Namespace) -> SupervisorService:
    return SupervisorService(session, cell, service_data_dir(options.data_dir, cell, "supervisor"))

