"""Service runtime: queryables served from channels by worker threads, typed error replies, liveliness.

Every service subclasses :class:`Service`. Its constructor registers handlers
with :meth:`Service.handle` (one per endpoint of ``fabric.wire.keys.ENDPOINTS``
for that service; :meth:`Service.start` refuses to start when one is missing or
unknown) and publishers with :meth:`Service.publisher`; :meth:`Service.start`
declares the queryables, then the liveliness token (so "alive" means "ready
to serve"). Every service answers ``health`` (:mod:`fabric.server.health`).
Queries arrive in a FIFO channel and are answered by a worker thread: nothing
runs inside a Zenoh callback. A handler returns the reply
message or raises a :class:`~fabric.wire.errors.FabricError`, which becomes a
``reply_err`` with a code, a message and details. Any other exception is logged
with its traceback, answered as ``internal`` and marks the service degraded
(its ``health`` says which command failed and how).
"""
from __future__ import annotations

import fcntl
import logging
import os
import tempfile
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import zenoh

from fabric.client import Client
from fabric.client.sessions import wait_connected
from fabric.schemas import Ack, Artifact, ErrorReply, PinRequest
from fabric.server.disk import disk_full_of
from fabric.server.health import Health
from fabric.store.artifacts import ArtifactStore
from fabric.store.records import RecordStore
from fabric.wire import codec
from fabric.wire.errors import FabricError, InternalError, NotFound, StateError, ValidationError
from fabric.wire.keys import ENDPOINTS, SERVICES, TOPICS, Endpoint, Keys, endpoints_of
from fabric.wire.qos import reply_qos

__all__ = ["Service", "Publisher", "reply_error", "lock_dir"]

log = logging.getLogger("fabric.server.service")
LINK_WINDOW_S = 3.0     # how long start() waits for a first link before asking who else serves the cell
Handler = Callable[[Any], Any]


def reply_error(query: zenoh.Query, err: FabricError) -> None:
    """Answer ``query`` with a typed error payload."""
    wire = err.to_wire()
    query.reply_err(codec.encode(ErrorReply(code=wire["code"], message=wire["message"], details=wire["details"])))


class Publisher:
    """A declared publisher for one telemetry topic; ``send`` encodes a schema message."""

    def __init__(self, session: zenoh.Session, key: str, msg_type: type[Any], lossless: bool) -> None:
        self.key, self.msg_type = key, msg_type
        cc = zenoh.CongestionControl.BLOCK if lossless else zenoh.CongestionControl.DROP
        self._pub = session.declare_publisher(key, congestion_control=cc,
                                              reliability=zenoh.Reliability.RELIABLE)

    def send(self, msg: Any) -> None:
        if not isinstance(msg, self.msg_type):
            raise TypeError(f"{self.key} carries {self.msg_type.TYPE}, not {type(msg).__name__}")
        self._pub.put(codec.encode(msg))

    def send_encoded(self, data: bytes) -> None:
        """Publish a message the caller already encoded (``codec.encode`` of this topic's type), e.g. one
        it also keeps as a snapshot reply."""
        self._pub.put(data)

    def close(self) -> None:
        self._pub.undeclare()


class Service:
    """Base of the five services; see the module docstring for the life cycle."""

    name = "service"
    partial = False             # a stand-in for tests may serve only some of its endpoints (never unknown ones)

    def __init__(self, session: zenoh.Session, cell_id: str, data_dir: str | Path | None = None) -> None:
        """``cell_id``: the cell's name on the fabric; ``data_dir``: this service's folder of durable state
        (artifacts, its database); None: a temporary folder removed on :meth:`close` (tests, throw-away runs)."""
        if self.name not in SERVICES:
            raise TypeError(f"service class {type(self).__name__} names {self.name!r}, not one of {SERVICES}")
        self.session = session
        self.cell_id = cell_id
        self.keys = Keys(cell_id)
        self.log = logging.getLogger(f"fabric.{self.name}")
        self.health = Health(self.name)
        self.started_s = time.time()
        self._handlers: dict[str, tuple[Endpoint, Handler]] = {}
        self._handler_workers: dict[str, int] = {}          # command -> worker threads taking its queries
        self._snapshots: dict[str, tuple[Endpoint, Callable[[], bytes]]] = {}
        self._publishers: list[Publisher] = []
        self._queryables: list[Any] = []
        self._threads: list[threading.Thread] = []
        self._token: Any = None
        self._served: frozenset[str] = frozenset()      # the commands served, once started (see _answer_unknown)
        self._tmp = tempfile.TemporaryDirectory(prefix=f"am-fabric-{self.name}-") if data_dir is None else None
        self.data_dir = Path(self._tmp.name) if self._tmp is not None else Path(str(data_dir))
        self._dir_lock = lock_dir(self.data_dir, self.name, cell_id)
        self.artifacts = ArtifactStore(self.data_dir / "artifacts")
        self.records = RecordStore(self.data_dir / "records.sqlite")
        self.closed = threading.Event()
        self.handle("health", lambda _: self.health.report())

    @property
    def degraded(self) -> str | None:
        """Why the service is degraded (None when healthy)."""
        return self.health.degraded

    # --- declaration -------------------------------------------------------

    def handle(self, command: str, fn: Handler, workers: int = 1) -> None:
        """Serve endpoint ``(self.name, command)`` with ``fn(request) -> reply``; ``workers`` threads take its
        queries from one channel (more than one: ``fn`` runs concurrently, and must be safe to)."""
        ep = ENDPOINTS[(self.name, command)]
        self._handlers[command] = (ep, fn)
        self._handler_workers[command] = max(1, int(workers))

    def handle_snapshot(self, command: str, current: Callable[[], bytes]) -> None:
        """Serve read-only endpoint ``(self.name, command)`` from a reply the service keeps encoded and
        current: ``current()`` returns it (a reference read: no lock, no work). Such a query is answered
        in Zenoh's own thread as it arrives, not handed to a worker thread, so under load it waits for
        no other thread of the service."""
        ep = ENDPOINTS[(self.name, command)]
        self._snapshots[command] = (ep, current)

    def publisher(self, topic: str, *, lossless: bool = False) -> Publisher:
        pub = Publisher(self.session, self.keys.topic(self.name, topic), TOPICS[(self.name, topic)], lossless)
        self._publishers.append(pub)
        return pub

    def store_artifact(self, artifact: Artifact) -> str:
        """Keep a content-addressed result on disk, served at ``<service>/artifact/<id>``."""
        return self.artifacts.put(artifact)

    def serve_pins(self) -> None:
        """Serve the ``pin`` endpoint: jobs pin the artifacts they need here (see ArtifactStore)."""
        self.handle("pin", self._on_pin)

    def _on_pin(self, req: PinRequest) -> Ack:
        if not req.pinned:
            self.artifacts.unpin(req.owner)
            return Ack(ok=True, message=f"released the pins of {req.owner}")
        known = self.artifacts.has(req.artifact_id) or self.get_artifact(req.artifact_id) is not None
        if not known:                                          # (a service may hold some in memory first)
            raise NotFound(f"no artifact {req.artifact_id} at {self.name}", artifact_id=req.artifact_id)
        self.artifacts.pin(req.artifact_id, req.owner)
        return Ack(ok=True, message=f"pinned {req.artifact_id[:12]} for {req.owner}")

    def get_artifact(self, artifact_id: str) -> Artifact | None:
        """A stored artifact, or None when it is not (or no longer) here."""
        try:
            return self.artifacts.get(artifact_id)
        except (NotFound, ValidationError):
            return None

    # --- life cycle ---------------------------------------------------------

    def start(self) -> None:
        """Serve every endpoint, then declare the liveliness token. Refuses (StateError) when another
        service of the same role already serves this cell anywhere on the fabric."""
        wait_connected(self.session, LINK_WINDOW_S)    # the check asks the fabric: a link must be up first
        # Client.alive asks again (and merges) when a peer session's answer comes back incomplete
        self._check_handlers()
        if Client(self.session, self.keys.cell).alive(timeout=1.0).get(self.name):
            raise StateError(f"a {self.name} is already serving cell {self.keys.cell!r}: stop it first, or run this "
                             f"one with another --cell", state="running", command="start", service=self.name)
        for command, (ep, fn) in self._handlers.items():
            self._serve(self.keys.cmd(self.name, command), self._answerer(ep, fn), self._handler_workers[command])
        for command, (ep, current) in self._snapshots.items():
            answer = lambda q, ep=ep, current=current: self._answer_snapshot(q, ep, current)  # noqa: E731
            self._queryables.append(self.session.declare_queryable(self.keys.cmd(self.name, command), answer))
        self._serve(self.keys.artifact_all(self.name), self._answer_artifact)
        # last of the queryables: the catch-all that answers the commands this service does not serve
        self._served = frozenset(self._handlers) | frozenset(self._snapshots)
        self._queryables.append(self.session.declare_queryable(self.keys.cmd(self.name, "**"), self._answer_unknown))
        self._token = self.session.liveliness().declare_token(self.keys.alive(self.name))
        self.log.info("%s serving %d commands on %s", self.name, len(self._handlers) + len(self._snapshots),
                      self.keys.prefix)

    def _check_handlers(self) -> None:
        """Every endpoint of this service in the table has exactly one handler, and nothing else does."""
        declared = {e.command for e in endpoints_of(self.name)}
        served = list(self._handlers) + list(self._snapshots)
        missing, extra = (set() if self.partial else declared - set(served)), set(served) - declared
        twice = set(self._handlers) & set(self._snapshots)
        if missing or extra or twice:
            raise TypeError(f"{self.name} serves {sorted(served)} but the endpoint table declares "
                            f"{sorted(declared)} (missing {sorted(missing)}, unknown {sorted(extra)}, "
                            f"twice {sorted(twice)})")

    def _serve(self, key: str, answer: Callable[[zenoh.Query], None], workers: int = 1) -> None:
        q = self.session.declare_queryable(key, handler=zenoh.handlers.FifoChannel(1024))
        self._queryables.append(q)
        for k in range(workers):
            t = threading.Thread(target=self._worker, args=(q, answer), name=f"{self.name}:{key}:{k}", daemon=True)
            t.start()
            self._threads.append(t)

    def _worker(self, q: Any, answer: Callable[[zenoh.Query], None]) -> None:
        for query in q:  # ends when the queryable is undeclared
            with query:
                answer(query)

    def _answerer(self, ep: Endpoint, fn: Handler) -> Callable[[zenoh.Query], None]:
        def answer(query: zenoh.Query) -> None:
            self._answer(query, ep, fn)
        return answer

    def _answer(self, query: zenoh.Query, ep: Endpoint, fn: Handler) -> None:
        try:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            req: Any = codec.decode(payload, ep.request)
            reply = fn(req)
            query.reply(query.key_expr, codec.encode(reply), **reply_qos(ep))
        except FabricError as err:
            if isinstance(err, ValidationError):       # a handler's check of the request: that message's field
                err.details.setdefault("schema", ep.request.TYPE)
            self.log.info("%s/%s: %s: %s", self.name, ep.command, err.code, err.message)
            reply_error(query, err)
        except Exception as exc:  # noqa: BLE001 - a full disk, or a bug: answer, log, mark degraded, keep serving
            full = disk_full_of(exc, self.name, self.data_dir)
            if full is not None:
                self.health.degrade("disk", full.message)
                self.log.error("%s/%s: %s", self.name, ep.command, full.message)
                reply_error(query, full)
                return
            self.health.degrade(f"handler:{ep.command}", f"{type(exc).__name__}: {exc}")
            self.log.error("%s/%s failed:\n%s", self.name, ep.command, traceback.format_exc())
            reply_error(query, InternalError(f"{self.name}/{ep.command} failed: {type(exc).__name__}: {exc}",
                                             service=self.name, command=ep.command))

    def _answer_snapshot(self, query: zenoh.Query, ep: Endpoint, current: Callable[[], bytes]) -> None:
        """In Zenoh's callback: check the request, reply with the current encoded snapshot. Never blocks."""
        with query:
            try:
                codec.decode(query.payload.to_bytes() if query.payload is not None else b"", ep.request)
                query.reply(query.key_expr, current(), **reply_qos(ep))
            except FabricError as err:
                reply_error(query, err)

    def _answer_unknown(self, query: zenoh.Query) -> None:
        """The catch-all on ``am/<cell>/<service>/cmd/**``, in Zenoh's callback (never blocks): a key of a command
        this service does not serve gets a typed ``not_found`` at once, naming the commands it serves. A command
        it serves is left to that command's queryable (this one drops the query unanswered), and so is a wildcard
        query (``am/<cell>/*/cmd/health``): every command has exactly one reply."""
        with query:
            key = str(query.key_expr)
            prefix = self.keys.cmd(self.name, "")
            command = key[len(prefix):] if key.startswith(prefix) else ""
            if "*" in key or command in self._served:
                return
            served = sorted(self._served)
            reply_error(query, NotFound(f"the {self.name} of cell {self.keys.cell!r} has no command {command!r}; "
                                        f"its commands: {', '.join(served)}", service=self.name, command=command,
                                        commands=served))

    def _answer_artifact(self, query: zenoh.Query) -> None:
        try:
            art_id = self.keys.parse_artifact(str(query.key_expr))
        except ValueError as exc:
            reply_error(query, FabricError(str(exc)))
            return
        art = self.get_artifact(art_id)
        if art is None:
            reply_error(query, NotFound(f"no artifact {art_id} at {self.name}", artifact_id=art_id))
        else:
            query.reply(query.key_expr, codec.encode(art))

    def close(self) -> None:
        """Undeclare everything (token first, so peers see us leave at once)."""
        if self.closed.is_set():
            return
        self.closed.set()
        if self._token is not None:
            self._token.undeclare()
        for q in self._queryables:
            q.undeclare()
        for p in self._publishers:
            p.close()
        for t in self._threads:
            t.join(timeout=2.0)
        self.artifacts.close()
        self.records.close()
        self._dir_lock.close()
        if self._tmp is not None:
            self._tmp.cleanup()


def lock_dir(path: Path, name: str, cell: str) -> IO[bytes]:
    """Hold an exclusive lock on ``path`` for this process's life: two services of one role and cell on
    one host would write the same durable state (the liveliness check covers other hosts).

    The lock is ``flock`` on ``path/lock``: the kernel releases it when its holder dies, however it
    dies, so a dead holder never blocks (the descriptor is close-on-exec, so no program the service
    runs inherits it). The file records the holder's pid and command line, for the refusal to name."""
    path.mkdir(parents=True, exist_ok=True)
    # held for the life of the process; "a", not "w": a refused contender must not erase the holder's pid
    fh = open(path / "lock", "a+b")  # noqa: SIM115
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        fh.seek(0)
        holder = fh.read(512).decode("utf-8", "replace").strip()
        fh.close()
        raise StateError(f"a {name} of cell {cell!r} is already running on this host (it holds {path}/lock"
                         + (f": {_lock_holder(holder)}" if holder else "") + ")",
                         state="running", command="start", service=name) from None
    fh.truncate(0)
    fh.write(f"{os.getpid()} {_command_line(os.getpid())}\n".encode())
    fh.flush()
    return fh


def _command_line(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as cmd:
            return cmd.read().replace(b"\0", b" ").decode("utf-8", "replace").strip()[:300]
    except OSError:
        return ""


def _lock_holder(recorded: str) -> str:
    """Who holds a lock, from what the lock file records (``pid command``)."""
    pid_text, _, command = recorded.partition(" ")
    try:
        pid = int(pid_text)
    except ValueError:
        return recorded[:200]
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        # the recorded holder is dead, so whoever holds the lock now inherited its descriptor
        return f"pid {pid} recorded it, but is gone: another process inherited the lock"
    except PermissionError:
        pass
    return f"pid {pid}" + (f", {command}" if command else "")
