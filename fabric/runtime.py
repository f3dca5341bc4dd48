"""Service runtime: queryables served from channels by worker threads, typed error replies, liveliness.

Every service subclasses :class:`Service`. Its constructor registers handlers
with :meth:`Service.handle` (one per endpoint of ``fabric.keys.ENDPOINTS``)
and publishers with :meth:`Service.publisher`; :meth:`Service.start`
declares the queryables, then the liveliness token (so "alive" means "ready
to serve"). Queries arrive in a FIFO channel and are answered by a worker
thread: nothing runs inside a Zenoh callback. A handler returns the reply
message or raises a :class:`~fabric.errors.FabricError`, which becomes a
``reply_err`` with a code, a message and details. Any other exception is logged
with its traceback, answered as ``internal`` and marks the service degraded.
"""
from __future__ import annotations

import logging
import threading
import time
import traceback
from typing import Any, Callable

import zenoh

from fabric import codec
from fabric.errors import FabricError, InternalError, NotFound
from fabric.keys import ENDPOINTS, TOPICS, Endpoint, Keys
from fabric.schemas import Artifact, ErrorReply

__all__ = ["Service", "Publisher", "reply_error"]

log = logging.getLogger("fabric.runtime")
Handler = Callable[[Any], Any]


def reply_error(query: zenoh.Query, err: FabricError) -> None:
    """Answer ``query`` with a typed error payload."""
    wire = err.to_wire()
    query.reply_err(codec.encode(ErrorReply(code=wire["code"], message=wire["message"], details=wire["details"])))


class Publisher:
    """A declared publisher for one telemetry topic; ``send`` encodes a schema message."""

    def __init__(self, session: zenoh.Session, key: str, msg_type: type, lossless: bool) -> None:
        self.key, self.msg_type = key, msg_type
        cc = zenoh.CongestionControl.BLOCK if lossless else zenoh.CongestionControl.DROP
        self._pub = session.declare_publisher(key, congestion_control=cc,
                                              reliability=zenoh.Reliability.RELIABLE)

    def send(self, msg: Any) -> None:
        if not isinstance(msg, self.msg_type):
            raise TypeError(f"{self.key} carries {self.msg_type.TYPE}, not {type(msg).__name__}")
        self._pub.put(codec.encode(msg))

    def close(self) -> None:
        self._pub.undeclare()


class Service:
    """Base of the five services; see the module docstring for the life cycle."""

    name = "service"

    def __init__(self, session: zenoh.Session, cell: str) -> None:
        self.session = session
        self.keys = Keys(cell)
        self.log = logging.getLogger(f"fabric.{self.name}")
        self.degraded: str | None = None
        self.started_s = time.time()
        self._handlers: dict[str, tuple[Endpoint, Handler]] = {}
        self._publishers: list[Publisher] = []
        self._queryables: list[Any] = []
        self._threads: list[threading.Thread] = []
        self._token: Any = None
        self._artifacts: dict[str, Artifact] = {}
        self._artifact_bytes = 0
        self._lock = threading.Lock()
        self.closed = threading.Event()

    # --- declaration -------------------------------------------------------

    def handle(self, command: str, fn: Handler) -> None:
        """Serve endpoint ``(self.name, command)`` with ``fn(request) -> reply``."""
        ep = ENDPOINTS[(self.name, command)]
        self._handlers[command] = (ep, fn)

    def publisher(self, topic: str, *, lossless: bool = False) -> Publisher:
        pub = Publisher(self.session, self.keys.topic(self.name, topic), TOPICS[(self.name, topic)], lossless)
        self._publishers.append(pub)
        return pub

    def store_artifact(self, artifact: Artifact, max_total_bytes: int = 2 << 30) -> str:
        """Keep a content-addressed result, served at ``<service>/artifact/<id>``; oldest evicted first."""
        with self._lock:
            if artifact.artifact_id not in self._artifacts:
                self._artifacts[artifact.artifact_id] = artifact
                self._artifact_bytes += len(artifact.data)
            while self._artifact_bytes > max_total_bytes and len(self._artifacts) > 1:
                old = next(iter(self._artifacts))
                self._artifact_bytes -= len(self._artifacts.pop(old).data)
        return artifact.artifact_id

    def get_artifact(self, artifact_id: str) -> Artifact | None:
        with self._lock:
            return self._artifacts.get(artifact_id)

    # --- life cycle ---------------------------------------------------------

    def start(self) -> None:
        for command, (ep, fn) in self._handlers.items():
            self._serve(self.keys.cmd(self.name, command), lambda q, ep=ep, fn=fn: self._answer(q, ep, fn))
        self._serve(self.keys.artifact_all(self.name), self._answer_artifact)
        self._token = self.session.liveliness().declare_token(self.keys.alive(self.name))
        self.log.info("%s serving %d commands on %s", self.name, len(self._handlers), self.keys.prefix)

    def _serve(self, key: str, answer: Callable[[zenoh.Query], None]) -> None:
        q = self.session.declare_queryable(key, handler=zenoh.handlers.FifoChannel(1024))
        self._queryables.append(q)
        t = threading.Thread(target=self._worker, args=(q, answer), name=f"{self.name}:{key}", daemon=True)
        t.start()
        self._threads.append(t)

    def _worker(self, q: Any, answer: Callable[[zenoh.Query], None]) -> None:
        for query in q:  # ends when the queryable is undeclared
            with query:
                answer(query)

    def _answer(self, query: zenoh.Query, ep: Endpoint, fn: Handler) -> None:
        try:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            req = codec.decode(payload, ep.request)
            reply = fn(req)
            query.reply(query.key_expr, codec.encode(reply))
        except FabricError as err:
            self.log.info("%s/%s: %s: %s", self.name, ep.command, err.code, err.message)
            reply_error(query, err)
        except Exception as exc:  # a bug: answer, log the traceback, mark degraded, keep serving
            self.degraded = f"{ep.command}: {type(exc).__name__}: {exc}"
            self.log.error("%s/%s failed:\n%s", self.name, ep.command, traceback.format_exc())
            reply_error(query, InternalError(f"{self.name}/{ep.command} failed: {type(exc).__name__}: {exc}",
                                             service=self.name, command=ep.command))

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
