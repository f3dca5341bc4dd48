"""Thin typed client: one method per endpoint, typed exceptions, explicit timeouts, subscriptions.

    with Client.connect(SessionSettings(cell="cell1")) as fab:
        print(fab.position())
        for pose in fab.subscribe("station", "pose"):
            ...

Every call is a Zenoh ``get`` on the endpoint's key with the endpoint's
timeout (or the one given). An error reply raises the matching
:class:`~fabric.wire.errors.FabricError` subclass; no reply raises
:class:`~fabric.wire.errors.ServiceUnavailable`.
"""
from __future__ import annotations

import os
import queue
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, BinaryIO, cast

import zenoh

from fabric import schemas as s
from fabric.client.job_waits import wait_job, wait_print_job
from fabric.client.sessions import (
    CONNECT_WINDOW_S,
    check_role,
    error_of,
    open_session,
    refused_by_relay,
    relay_info,
    relay_named,
    wait_connected,
)
from fabric.client.subscriptions import AliveSubscription, Subscription
from fabric.client.transfers import EXPORT_CHUNK_BYTES, export_to_file, input_size, upload_file
from fabric.schemas.states import PrintJob
from fabric.schemas.upload import UPLOAD_CHUNK_BYTES
from fabric.wire import codec
from fabric.wire.config import SessionSettings
from fabric.wire.errors import FabricError, NotFound, ServiceUnavailable
from fabric.wire.keys import (
    ALIVE_EVERY_CELL,
    ARTIFACT_SOURCES,
    ARTIFACT_TIMEOUT_S,
    ENDPOINTS,
    SERVICES,
    TOPICS,
    Endpoint,
    Keys,
    parse_alive,
)
from fabric.wire.qos import BULK_QOS, command_qos

__all__ = ["Client", "Subscription", "AliveSubscription", "wait_connected", "input_size"]

DISCOVERY_WINDOW_S = 1.0   # retry a get that found no queryable for this long (declarations in flight)
ALIVE_ATTEMPTS = 5         # liveliness queries merged when an answer is incomplete (see Client.alive)
ALIVE_BACKOFF_S = 0.01     # pause between those attempts
ALIVE_SETTLE_S = 0.4       # how long an empty liveliness answer is asked again (see Client.alive)
ALIVE_BACKOFF_MAX_S = 0.1  # ... the pause doubling from ALIVE_BACKOFF_S up to this


class Client:
    """Typed access to one cell's services over a Zenoh session."""

    def __init__(self, session: zenoh.Session, cell: str, role: str | None = None) -> None:
        """``role``: the role of this session's credentials on a secured fabric (None: no local check)."""
        self.session = session
        self.keys = Keys(cell)
        self.role = role
        self._relay: dict[str, Any] | bool | None = False     # what the relay says of itself (False: not asked)

    @classmethod
    @contextmanager
    def connect(cls, settings: SessionSettings, window_s: float = CONNECT_WINDOW_S) -> Iterator[Client]:
        """Open a session from ``settings`` and close it on exit; ``window_s``: how long to wait for the hub
        (one that is starting)."""
        from fabric.security.zconfigs import role_of_config
        session = open_session(settings, window_s)
        try:
            if settings.connect:
                wait_connected(session, window_s)
            yield cls(session, settings.cell, role_of_config(settings.config_file))
        finally:
            session.close()

    # --- generic -----------------------------------------------------------

    def call(self, service: str, command: str, request: Any = None, timeout: float | None = None) -> Any:
        """Ask ``service/command`` with ``request`` (None: the endpoint's empty request) and wait at most
        ``timeout`` (None: the endpoint's); the typed reply, or the typed error of the reply raised."""
        ep = _endpoint(service, command)
        if self.role is not None:
            check_role(self.role, service, command)
        req = request if request is not None else ep.request()
        if not isinstance(req, ep.request):
            raise TypeError(f"{service}/{command} takes {ep.request.TYPE}, not {type(req).__name__}")
        return self.call_raw(service, command, codec.encode(req), ep.reply, timeout or ep.timeout_s)

    def call_raw(self, service: str, command: str, payload: bytes, reply_type: type, timeout: float) -> Any:
        """Ask ``service/command`` with an already encoded request (e.g. one of an older version)."""
        key = self.keys.cmd(service, command)
        return self._get_one(key, payload, reply_type, timeout, f"{service}/{command}",
                             command_qos(_endpoint(service, command)), service, command)

    def _get_one(self, key: str, payload: bytes | None, reply_type: type, timeout: float, what: str,
                 qos: dict[str, Any] = BULK_QOS, service: str = "", command: str = "") -> Any:
        # A get with no matching queryable returns at once; right after a service (or this session)
        # starts, its declaration may still be on the way: retry for a short, bounded window. The first
        # reply is taken (no consolidation): a key has one answering queryable (a service's catch-all on
        # <service>/cmd/** stays silent for the commands it serves), so it is the answer, a success or an error.
        t0 = time.monotonic()
        while True:
            t_get = time.monotonic()
            try:
                replies = self.session.get(key, payload=payload, timeout=timeout, **qos)
            except zenoh.ZError as exc:          # this session was closed (e.g. the console is quitting)
                raise ServiceUnavailable(f"cannot ask {what}: the fabric session is closed ({exc})",
                                         key=key) from None
            for reply in replies:
                if reply.ok is not None:
                    return codec.decode(reply.ok.payload.to_bytes(), reply_type)
                raise error_of(reply.err.payload.to_bytes(), what, time.monotonic() - t0)
            waited = time.monotonic() - t0
            timed_out = time.monotonic() - t_get >= 0.9 * timeout
            if command and self._relay is False:     # no one answered: on a relay that may be why
                self._relay = relay_info(self.session)
                refused_by_relay(self._relay, self.role, service, command)
            if timed_out or waited >= min(timeout, DISCOVERY_WINDOW_S):
                break
            time.sleep(0.05)
        if timed_out:
            raise ServiceUnavailable(f"no reply from {what} within {waited:.3g} s (the service is there but did "
                                     f"not answer: busy, frozen or cut off)", key=key, timeout_s=waited,
                                     reason="no_reply")
        raise self._nobody(what, key, service, waited, timeout)

    def _nobody(self, what: str, key: str, service: str, waited: float, timeout: float) -> ServiceUnavailable:
        """Nothing serves ``key``: an unknown cell or a service that is not running, told apart by the liveliness
        of every cell (one query, answered by the hub; bounded by what is left of ``timeout``, at least 0.5 s: a
        busy hub answers late, and a late answer would name the wrong cause).
        ``details['reason']``: ``no_cell`` (``details['cells']``: every cell present and its services),
        ``service_down`` (``details['alive']``: the cell's services alive), or ``no_queryable``."""
        head = f"no {what} on the fabric (asked for {waited:.2g} s{relay_named(self._relay)})"
        cell = self.keys.cell
        try:
            cells = self.cells(timeout=max(0.5, min(1.0, timeout - waited)), attempts=ALIVE_ATTEMPTS,
                               enough=lambda found: service in found.get(cell, ()))
        except zenoh.ZError:                     # the session closed meanwhile: say what is known
            return ServiceUnavailable(f"{head}: is the service running and is the cell name right?", key=key,
                                      timeout_s=waited, reason="no_queryable")
        if cell not in cells:
            present = "; ".join(f"{c} ({', '.join(svcs)})" for c, svcs in cells.items()) or "none"
            return ServiceUnavailable(f"{head}: no service of cell {cell!r} is on the fabric (cells present: "
                                      f"{present}); is the cell name right (--cell, $FABRIC_CELL)?", key=key,
                                      timeout_s=waited, reason="no_cell", cell=cell, cells=cells)
        alive = cells[cell]
        if service and service not in alive:
            return ServiceUnavailable(f"{head}: cell {cell!r} has no {service} running (alive: {', '.join(alive)}); "
                                      f"start it (fabric-cli up, or fabric-cli serve {service})", key=key,
                                      timeout_s=waited, reason="service_down", cell=cell, service=service,
                                      alive=alive)
        return ServiceUnavailable(f"{head}: nothing on cell {cell!r} serves {key}", key=key, timeout_s=waited,
                                  reason="no_queryable", cell=cell, alive=alive)

    def subscribe(self, service: str, topic: str) -> Subscription:
        return Subscription(self.session, self.keys.topic(service, topic), TOPICS[(service, topic)])

    def subscribe_alive(self, on_change: Callable[[str, bool], None] | None = None) -> AliveSubscription:
        """Follow services appearing and vanishing (liveliness tokens); close it when done.

        Without ``on_change`` read the changes with ``get()``; with it, each change calls
        ``on_change(service, alive)`` from the Zenoh callback (which must not block)."""
        return AliveSubscription(self.session, self.keys.alive_all(), on_change)

    def alive(self, timeout: float = 2.0) -> dict[str, bool]:
        """Which services hold a liveliness token now (answers without the supervisor).

        The hub answers and the query returns at once; ``timeout`` only bounds the wait when
        no one answers. A *peer* session's liveliness query sometimes returns at once with an
        empty or partial answer while links to other peers are busy (measured here: 53 of 300
        queries under load; 0 of 300 for a client session), so an incomplete answer is asked
        again, up to ``ALIVE_ATTEMPTS`` times within ``timeout`` (10 ms apart), and the answers are
        merged: a service that is really gone costs some 50 ms more to report. An answer with no service
        at all is asked again for up to ``ALIVE_SETTLE_S`` (within ``timeout``), the pause doubling: CI saw
        five empty answers 10 ms apart from a CLI in another network namespace right after its
        ``status --wait`` had seen every service (a cell really gone costs that much more to report).
        """
        found: set[str] = set()
        start = time.monotonic()
        end, settle_end = start + timeout, start + min(timeout, ALIVE_SETTLE_S)
        pause_s, attempts = ALIVE_BACKOFF_S, 0
        while True:
            left = end - time.monotonic()
            if left <= 0:
                break
            for reply in self.session.liveliness().get(self.keys.alive_all(), timeout=left):
                if reply.ok is not None:
                    found.add(parse_alive(str(reply.ok.key_expr))[1])
            attempts += 1
            if found >= set(SERVICES):
                break
            if found and attempts >= ALIVE_ATTEMPTS:
                break
            if not found:
                if time.monotonic() + pause_s > settle_end:
                    break
                time.sleep(pause_s)
                pause_s = min(2 * pause_s, ALIVE_BACKOFF_MAX_S)
            else:
                time.sleep(ALIVE_BACKOFF_S)
        return {name: name in found for name in SERVICES}

    def cells(self, timeout: float = 2.0, attempts: int = 1,
              enough: Callable[[dict[str, set[str]]], bool] | None = None) -> dict[str, list[str]]:
        """Every cell present on the fabric: cell name -> the services that hold a liveliness token.

        ``attempts`` > 1 merges that many queries (10 ms apart, within ``timeout``) unless ``enough(found)``
        says the answer so far suffices: a peer session's answer can come back incomplete (see :meth:`alive`)."""
        found: dict[str, set[str]] = {}
        end = time.monotonic() + timeout
        for attempt in range(max(1, attempts)):
            left = end - time.monotonic()
            if left <= 0:
                break
            for reply in self.session.liveliness().get(ALIVE_EVERY_CELL, timeout=left):
                if reply.ok is not None:
                    cell, service = parse_alive(str(reply.ok.key_expr))
                    found.setdefault(cell, set()).add(service)
            if enough is not None and enough(found):
                break
            if attempt < attempts - 1:
                time.sleep(ALIVE_BACKOFF_S)
        return {cell: sorted(services) for cell, services in sorted(found.items())}

    def health(self, service: str) -> s.Health:
        """One service's own health: ok, or degraded with the reasons."""
        return self.call(service, "health")

    def healths(self, timeout: float = 2.0) -> dict[str, s.Health]:
        """The health of every service of the cell that answers within ``timeout``, in one query."""
        ep = ENDPOINTS[(SERVICES[0], "health")]
        found: dict[str, s.Health] = {}
        replies = self.session.get(self.keys.health_all(), payload=codec.encode(s.Empty()), timeout=timeout,
                                   **command_qos(ep))
        for reply in replies:
            if reply.ok is not None:
                h = codec.decode(reply.ok.payload.to_bytes(), s.Health)
                found[h.service] = h
        return found

    def wait_alive(self, services: tuple[str, ...] = SERVICES, deadline_s: float = 30.0) -> None:
        """Block until every service is alive, or raise ServiceUnavailable naming the missing ones.

        The truth is a liveliness query (answered by the hub); liveliness changes only wake the wait
        up early. (A subscriber's history can replay a token that was undeclared while no subscriber
        was listening, so it is not trusted on its own.)
        """
        end = time.monotonic() + deadline_s
        changes = self.subscribe_alive()
        try:
            while True:
                alive = {k for k, v in self.alive(timeout=2.0).items() if v}
                if set(services) <= alive:
                    return
                left = end - time.monotonic()
                if left <= 0:
                    missing = sorted(set(services) - alive)
                    raise ServiceUnavailable(f"not alive after {deadline_s:g} s: {', '.join(missing)}",
                                             missing=missing)
                try:
                    changes.get(timeout=min(left, 1.0))
                except queue.Empty:
                    pass
        finally:
            changes.close()

    def artifact(self, service: str, artifact_id: str, timeout: float | None = None) -> s.Artifact:
        """A content-addressed artifact (G-code, a program, a model) by its id, from the service that keeps it;
        ``timeout`` None: the one the table declares (``fabric.wire.keys.ARTIFACT_SOURCES``)."""
        source = ARTIFACT_SOURCES.get(service)
        wait_s = timeout or (source.timeout_s if source is not None else ARTIFACT_TIMEOUT_S)
        return self._get_one(self.keys.artifact(service, artifact_id), None, s.Artifact, wait_s,
                             f"{service} artifact {artifact_id}", service=service)

    def wait_job(self, service: str, job_id: str, timeout: float = 600.0,
                 on_progress: Callable[[s.JobStatus], None] | None = None,
                 cancel: threading.Event | None = None) -> s.JobStatus:
        """Follow a job until it ends; raise its error if it failed (see :func:`fabric.client.job_waits.wait_job`)."""
        return wait_job(self, service, job_id, timeout, on_progress, cancel)

    def cancel_job(self, service: str, job_id: str, reason: str = "") -> s.JobStatus:
        """Cancel a slicing or planning job (queued: it never runs; running: it fails at its next step)."""
        return self.call(service, "cancel", s.JobCancel(job_id=job_id, reason=reason))

    # --- station: the paper's commands ------------------------------------------

    def position(self) -> s.Pose: return self.call("station", "position")
    def cell_info(self, timeout: float | None = None) -> s.CellInfo: return self.call("station", "cell", None, timeout)

    def station_cell(self, timeout: float = 2.0) -> s.CellInfo | None:
        """:meth:`cell_info`, or None when no station answers (for ``status``)."""
        try:
            return self.cell_info(timeout)
        except FabricError:
            return None

    def station_robot(self, timeout: float = 2.0) -> s.RobotStatus | None:
        """The robot the station drives, or None (the twin alone, or no station answers: for ``status``)."""
        try:
            return self.call("station", "state", timeout=timeout).robot
        except FabricError:
            return None

    def home(self) -> s.Ack: return self.call("station", "home")
    def jog(self, dx_mm: float = 0.0, dy_mm: float = 0.0, dz_mm: float = 0.0, speed_mm_s: float = 20.0) -> s.Ack:
        """A straight move of the nozzle by hand (plate frame), certified against the part first."""
        return self.call("station", "jog", s.JogRequest(dxyz_mm=[dx_mm, dy_mm, dz_mm], speed_mm_s=speed_mm_s))
    def extrude(self, length_mm: float, speed_mm_s: float = 2.0) -> s.Ack:
        """Push (> 0) or pull back (< 0) filament by hand, the robot still (a hot nozzle)."""
        return self.call("station", "extrude", s.ExtrudeRequest(length_mm=length_mm, speed_mm_s=speed_mm_s))
    def load(self, program_id: str, job_id: str = "") -> s.TimeInfo:
        return self.call("station", "load", s.LoadRequest(program_id=program_id, job_id=job_id))
    def start(self, rtf: float | None = None, from_layer: int = -1) -> s.Ack:
        return self.call("station", "start", s.StartRequest(rtf=rtf, from_layer=from_layer))
    def pause(self) -> s.Ack: return self.call("station", "pause")
    def resume(self, rtf: float | None = None) -> s.Ack:
        return self.call("station", "resume", s.StartRequest(rtf=rtf))
    def recover(self, rtf: float | None = None, from_layer: int = -1) -> s.Ack:
        return self.call("station", "recover", s.StartRequest(rtf=rtf, from_layer=from_layer))
    def stop(self) -> s.Ack: return self.call("station", "stop")
    def clear_plate(self) -> s.Ack: return self.call("station", "clear_plate")
    def collisions(self) -> s.CollisionReport: return self.call("station", "collisions")
    def calibrate(self) -> s.CalibrationReport: return self.call("station", "calibrate")
    def ready(self) -> s.ReadyReport: return self.call("station", "ready")
    def time(self) -> s.TimeInfo: return self.call("station", "time")
    def state(self) -> s.StationState: return self.call("station", "state")
    def events(self, since_seq: int = 0, limit: int = 10000, kinds: list[str] | None = None) -> s.EventList:
        return self.call("station", "events", s.EventsQuery(since_seq=since_seq, limit=limit, kinds=kinds or []))
    def overrides(self, **values: float | None) -> s.StationState:
        return self.call("station", "overrides", s.Overrides(**values))
    def set_rtf(self, rtf: float) -> s.StationState: return self.call("station", "rtf", s.StartRequest(rtf=rtf))
    def mesh(self, fmt: str = "stl") -> s.Artifact: return self.call("station", "mesh", s.MeshRequest(fmt=fmt))

    # --- pipeline --------------------------------------------------------------

    def slice(self, request: s.SliceRequest) -> s.JobAccepted: return self.call("slicer", "slice", request)
    def slice_result(self, gcode_id: str) -> s.SliceResult:
        return self.call("slicer", "result", s.ArtifactQuery(artifact_id=gcode_id))
    def backends(self) -> s.Backends: return self.call("slicer", "backends")
    def plan(self, request: s.PlanRequest) -> s.JobAccepted: return self.call("planner", "plan", request)

    def upload(self, service: str, path: str | os.PathLike[str], max_bytes: int,
               chunk_bytes: int = UPLOAD_CHUNK_BYTES,
               on_progress: Callable[[int, int], None] | None = None) -> str:
        """Send a file in pieces; returns the upload id (see :func:`fabric.client.transfers.upload_file`)."""
        return upload_file(self, service, path, max_bytes, chunk_bytes, on_progress)

    def plan_summary(self, program_id: str) -> s.PlanSummary:
        return self.call("planner", "summary", s.ArtifactQuery(artifact_id=program_id))
    def export(self, program_id: str, fmt: str, module_targets: int = 5000) -> s.Artifact:
        request = s.ExportRequest(program_id=program_id, fmt=fmt, module_targets=module_targets)
        return self.call("planner", "export", request)
    def export_chunk(self, program_id: str, fmt: str, offset: int = 0, limit_bytes: int = 4 << 20,
                     module_targets: int = 5000, *, job_id: str = "") -> s.ExportChunk:
        """One chunk of a streamed export (offset 0 starts it; then each offset where the last chunk ended).

        With ``job_id`` (and ``program_id`` empty) the program of that plan job, as soon as it exists."""
        return self.call("planner", "export_chunk", s.ExportChunkRequest(
            program_id=program_id, fmt=fmt, offset=offset, limit_bytes=limit_bytes, module_targets=module_targets,
            job_id=job_id))

    def export_to(self, program_id: str, fmt: str, out: BinaryIO, module_targets: int = 5000,
                  limit_bytes: int = EXPORT_CHUNK_BYTES, *, job_id: str = "") -> int:
        """Stream an export into ``out``; returns the bytes written (``fabric.client.transfers.export_to_file``)."""
        return export_to_file(self, program_id, fmt, out, module_targets, limit_bytes, job_id=job_id)

    def check(self, request: s.CollisionRequest) -> s.CollisionReport: return self.call("collision", "check", request)
    def status(self) -> s.FabricStatus: return self.call("supervisor", "status")
    def submit(self, request: s.JobSubmit) -> s.JobAccepted: return self.call("supervisor", "submit", request)
    def pin(self, service: str, artifact_id: str, owner: str) -> s.Ack:
        return self.call(service, "pin", s.PinRequest(artifact_id=artifact_id, owner=owner))
    def unpin(self, service: str, owner: str) -> s.Ack:
        return self.call(service, "pin", s.PinRequest(owner=owner, pinned=False))
    def job(self, job_id: str) -> s.JobRecord: return self.call("supervisor", "job", s.JobQuery(job_id=job_id))
    def jobs(self, offset: int = 0, limit: int = 100, states: Sequence[str] = ()) -> s.JobList:
        """A page of the print jobs in queue order (``limit`` up to ``s.MAX_JOBS_PAGE``; ``states``: only
        those); ``total`` says how many there are in all."""
        wanted = cast(list[PrintJob], list(states))        # the message turns them into members, or refuses
        return self.call("supervisor", "jobs", s.JobsQuery(offset=offset, limit=limit, states=wanted))
    def job_remove(self, job_id: str) -> s.Ack:
        return self.call("supervisor", "job_remove", s.JobQuery(job_id=job_id))
    def job_move(self, job_id: str, position: int) -> s.JobList:
        return self.call("supervisor", "job_move", s.JobMove(job_id=job_id, position=position))
    def job_next(self) -> s.Ack: return self.call("supervisor", "job_next")

    # --- the file library ---------------------------------------------------
    def files(self, offset: int = 0, limit: int = 100, name_contains: str = "") -> s.FileList:
        """A page of the supervisor's file library, most recently used first."""
        return self.call("supervisor", "files", s.FilesQuery(offset=offset, limit=limit, name_contains=name_contains))
    def file(self, file_id: str) -> s.LibraryFile:
        return self.call("supervisor", "file", s.FileQuery(file_id=file_id))
    def file_add(self, data: bytes, name: str, source: str = "") -> s.LibraryFile:
        return self.call("supervisor", "file_add", s.FileAdd(data=data, name=name, source=source))
    def file_remove(self, file_id: str) -> s.Ack:
        return self.call("supervisor", "file_remove", s.FileQuery(file_id=file_id))

    def wait_print_job(self, job_id: str, done: Callable[[s.JobRecord], bool], timeout: float = 600.0,
                       on_change: Callable[[s.JobRecord], None] | None = None) -> s.JobRecord:
        """Follow a print job until ``done(record)`` or a final state (``fabric.client.job_waits.wait_print_job``)."""
        return wait_print_job(self, job_id, done, timeout, on_change)


def _endpoint(service: str, command: str) -> Endpoint:
    """The endpoint ``service/command`` of the table; NotFound (as a service's catch-all says it) when there is none."""
    ep = ENDPOINTS.get((service, command))
    if ep is None:
        served = sorted(cmd for (svc, cmd) in ENDPOINTS if svc == service)
        raise NotFound(f"no command {service}/{command}" + (f"; {service} serves {', '.join(served)}" if served else
                                                           f"; services: {', '.join(SERVICES)}"),
                       service=service, command=command, commands=served)
    return ep
