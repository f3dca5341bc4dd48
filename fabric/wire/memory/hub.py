"""The memory fabric's hub: every session's declarations, and the routing of queries, samples and liveliness.

Keys match as in Zenoh: a query reaches every queryable whose key expression intersects the one asked
(``zenoh.KeyExpr.intersects``, which needs no session: wildcards and verbatim ``@`` chunks behave as on the
wire), a sample every subscriber, a liveliness query every token. Every session sees every declaration,
its own included (Zenoh's default locality).
"""
from __future__ import annotations

import threading
import uuid
from dataclasses import dataclass
from typing import Any

import zenoh

from fabric.wire.memory.channel import Dispatcher
from fabric.wire.memory.entities import MemoryQueryable, MemorySubscriber, MemoryToken
from fabric.wire.memory.query import MemoryQuery, Replies, Reply, Sample
from fabric.wire.memory.session import MemorySession

__all__ = ["MemoryFabric", "MemoryId"]

DRAIN_WAIT_S = 5.0


@dataclass(frozen=True)
class MemoryId:
    """A session's (or the hub's) id, as ``zenoh.ZenohId``: read with ``str()``."""

    hex: str

    @classmethod
    def new(cls) -> MemoryId:
        return cls(uuid.uuid4().hex)

    def __str__(self) -> str:
        return self.hex


class MemoryFabric:
    """An in-process fabric: sessions made by :meth:`session` reach each other as Zenoh sessions linked to one
    hub do. Close it (or use ``with``) to close every session and stop its callback thread."""

    def __init__(self, name: str = "memory-fabric") -> None:
        self.zid = MemoryId.new()                 # the hub: every session's one router
        self.dispatcher = Dispatcher(f"{name}:callbacks")
        self._lock = threading.Lock()
        self._queryables: list[MemoryQueryable] = []
        self._subscribers: list[MemorySubscriber] = []
        self._alive_subscribers: list[MemorySubscriber] = []
        self._tokens: list[MemoryToken] = []
        self._sessions: list[MemorySession] = []
        self.closed = False

    def session(self) -> MemorySession:
        """A new session on this fabric (a ``zenoh.Session`` stand-in: hand it to a ``Service`` or a ``Client``)."""
        if self.closed:
            raise zenoh.ZError("the memory fabric is closed")
        session = MemorySession(self, MemoryId.new())
        with self._lock:
            self._sessions.append(session)
        return session

    @property
    def callback_errors(self) -> list[BaseException]:
        """What callbacks raised so far (each is also logged): a test can assert there was none."""
        return self.dispatcher.errors

    def drain(self, timeout_s: float = DRAIN_WAIT_S) -> bool:
        """Wait until every callback due so far has run (samples, liveliness changes, queries to callbacks);
        False when they had not after ``timeout_s``. A test's way to wait for the fabric, never a sleep."""
        return self.dispatcher.drain(timeout_s)

    # --- declarations (by the sessions) ---------------------------------------------------

    def add(self, entity: Any, history: bool = False) -> None:
        """Route to a declared queryable, subscriber or token from now on (``history``: a liveliness subscriber
        first hears of the tokens present)."""
        with self._lock:
            if isinstance(entity, MemoryQueryable):
                self._queryables.append(entity)
            elif isinstance(entity, MemorySubscriber) and entity.liveliness:
                self._alive_subscribers.append(entity)
                for token in self._tokens if history else []:
                    if token.key_expr.intersects(entity.key_expr):
                        entity.offer(token.sample(zenoh.SampleKind.PUT))
            elif isinstance(entity, MemorySubscriber):
                self._subscribers.append(entity)
            elif isinstance(entity, MemoryToken):
                self._tokens.append(entity)
                self._tell_alive(entity, zenoh.SampleKind.PUT)

    def remove(self, entity: Any) -> None:
        """An undeclared entity (a token going is told to the liveliness subscribers)."""
        with self._lock:
            for entities in (self._queryables, self._subscribers, self._alive_subscribers, self._tokens):
                if entity in entities:
                    entities.remove(entity)
                    if isinstance(entity, MemoryToken):
                        self._tell_alive(entity, zenoh.SampleKind.DELETE)

    def forget_session(self, session: MemorySession) -> None:
        """A closed session (its entities are undeclared already)."""
        with self._lock:
            if session in self._sessions:
                self._sessions.remove(session)

    def _tell_alive(self, token: MemoryToken, kind: zenoh.SampleKind) -> None:
        for sub in self._alive_subscribers:
            if token.key_expr.intersects(sub.key_expr):
                sub.offer(token.sample(kind))

    # --- routing ------------------------------------------------------------------------------

    def query(self, key: zenoh.KeyExpr, payload: zenoh.ZBytes | None, timeout_s: float,
              hold_latest: bool) -> Replies:
        """Hand a query to every matching queryable; the replies, as ``get`` returns them."""
        replies = Replies(timeout_s, hold_latest)
        with self._lock:
            targets = [q for q in self._queryables if q.key_expr.intersects(key)]
        if not targets:
            replies.opened()
            replies.finalized()            # no one to ask: the get ends at once, as Zenoh's does
        for target in targets:
            target.offer(MemoryQuery(key, payload, replies))
        return replies

    def publish(self, sample: Sample) -> None:
        """Hand a sample to every matching subscriber."""
        with self._lock:
            targets = [sub for sub in self._subscribers if sub.key_expr.intersects(sample.key_expr)]
        for sub in targets:
            sub.offer(sample)

    def alive(self, key: zenoh.KeyExpr) -> Replies:
        """The tokens matching ``key``, as a liveliness query's replies (known at once)."""
        with self._lock:
            found = [Reply(ok=token.sample(zenoh.SampleKind.PUT)) for token in self._tokens
                     if token.key_expr.intersects(key)]
        return Replies.of(found)

    # --- life cycle ----------------------------------------------------------------------------

    def close(self) -> None:
        """Close every session, run the callbacks due, stop the callback thread."""
        if self.closed:
            return
        self.closed = True
        with self._lock:
            sessions = list(self._sessions)
        for session in sessions:
            session.close()
        self.dispatcher.close()

    def __enter__(self) -> MemoryFabric:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
