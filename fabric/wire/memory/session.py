"""A session of the memory fabric: the part of ``zenoh.Session`` that the fabric's services and client use.

:class:`fabric.server.service.Service` and its :class:`~fabric.server.service.Publisher`,
:class:`fabric.client.Client` with :mod:`fabric.client.subscriptions` and :mod:`fabric.client.sessions` call:

- ``declare_queryable(key, handler)`` with ``zenoh.handlers.FifoChannel`` (read by worker threads) or a
  callback; ``get(key, payload=, timeout=, priority=, express=, consolidation=)``;
- ``declare_publisher(key, congestion_control=, reliability=)`` and its ``put``; ``declare_subscriber``;
- ``liveliness()``: ``declare_token``, ``get`` and ``declare_subscriber(..., history=)``;
- ``info``: ``zid()``, ``routers_zid()`` (the hub, so ``wait_connected`` is true at once) and ``peers_zid()``;
- ``close()`` (and ``with``): every declaration undeclared, its tokens gone; any call after it raises
  ``zenoh.ZError``, as Zenoh's does.

A keyword argument Zenoh does not take is a ``TypeError`` here too. A ``get`` from a callback raises
:class:`BlockedCallback`: a callback never waits on the fabric (house rule 5), and here it would wait for itself.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import zenoh

from fabric.wire.memory.entities import (
    PUT_OPTIONS,
    MemoryPublisher,
    MemoryQueryable,
    MemorySubscriber,
    MemoryToken,
)
from fabric.wire.memory.query import Replies, Sample, check_options, to_key, to_zbytes

if TYPE_CHECKING:
    from fabric.wire.memory.hub import MemoryFabric, MemoryId

__all__ = ["MemorySession", "MemoryLiveliness", "MemoryInfo", "BlockedCallback"]

DEFAULT_QUERY_TIMEOUT_S = 10.0      # Zenoh's default (queries_default_timeout)
GET_OPTIONS = {"target", "accept_replies", "congestion_control", "priority", "express", "encoding", "attachment",
               "allowed_destination", "source_info", "cancellation_token", "timestamp_instrumentation"}
IMMEDIATE = (zenoh.ConsolidationMode.NONE, zenoh.ConsolidationMode.MONOTONIC)   # replies handed over on arrival


class BlockedCallback(RuntimeError):
    """A callback asked the fabric and would wait for an answer (house rule 5: a callback never blocks)."""


class MemoryInfo:
    """``session.info``: this session's id, and its one link (the hub, as a router)."""

    def __init__(self, session: MemorySession) -> None:
        self._session = session

    def zid(self) -> MemoryId:
        return self._session.zid()

    def routers_zid(self) -> list[MemoryId]:
        """The hub: a memory session is linked from the start."""
        return [self._session.fabric.zid]

    def peers_zid(self) -> list[MemoryId]:
        return []


class MemoryLiveliness:
    """``session.liveliness()``: tokens, who holds one now, and their changes."""

    def __init__(self, session: MemorySession) -> None:
        self._session = session

    def declare_token(self, key_expr: Any) -> MemoryToken:
        """A token present until undeclared or the session closes."""
        return self._session.declare(MemoryToken(self._session, key_expr))

    def get(self, key_expr: Any, handler: Any = None, *, timeout: float | None = None) -> Replies:
        """The tokens matching ``key_expr`` now (the hub knows them: answered at once)."""
        self._session.check_can_wait("liveliness().get", handler)
        return self._session.fabric.alive(to_key(key_expr))

    def declare_subscriber(self, key_expr: Any, handler: Any = None, *, history: bool | None = None
                           ) -> MemorySubscriber:
        """Tokens appearing (``SampleKind.PUT``) and going (``DELETE``); ``history``: those present first."""
        sub = MemorySubscriber(self._session, key_expr, handler, liveliness=True)
        return self._session.declare(sub, history=bool(history))


class MemorySession:
    """A ``zenoh.Session`` stand-in on a :class:`~fabric.wire.memory.hub.MemoryFabric` (module docstring)."""

    def __init__(self, fabric: MemoryFabric, zid: MemoryId) -> None:
        self.fabric = fabric
        self._zid = zid
        self._declared: list[Any] = []
        self._closed = False

    @property
    def info(self) -> MemoryInfo:
        return MemoryInfo(self)

    def zid(self) -> MemoryId:
        return self._zid

    def is_closed(self) -> bool:
        return self._closed

    def liveliness(self) -> MemoryLiveliness:
        self._check_open()
        return MemoryLiveliness(self)

    # --- declarations ----------------------------------------------------------------

    def declare_queryable(self, key_expr: Any, handler: Any = None, *, complete: bool | None = None,
                          allowed_origin: Any = None) -> MemoryQueryable:
        """Queries whose key intersects ``key_expr``, to ``handler`` (a callback, or a FIFO channel to read)."""
        return self.declare(MemoryQueryable(self, key_expr, handler))

    def declare_subscriber(self, key_expr: Any, handler: Any = None, *, allowed_origin: Any = None
                           ) -> MemorySubscriber:
        """Samples whose key intersects ``key_expr``, to ``handler`` (a callback, or a FIFO channel to read)."""
        return self.declare(MemorySubscriber(self, key_expr, handler))

    def declare_publisher(self, key_expr: Any, **options: Any) -> MemoryPublisher:
        """A publisher on ``key_expr`` (``options`` as Zenoh's: congestion control, reliability...)."""
        return self.declare(MemoryPublisher(self, key_expr, options))

    def declare(self, entity: Any, history: bool = False) -> Any:
        """Register a new entity of this session with the fabric (``history``: see ``MemoryFabric.add``)."""
        self._check_open()
        self._declared.append(entity)
        if not isinstance(entity, MemoryPublisher):
            self.fabric.add(entity, history=history)
        return entity

    def forget(self, entity: Any) -> None:
        """An entity of this session was undeclared."""
        if entity in self._declared:
            self._declared.remove(entity)
        self.fabric.remove(entity)

    # --- traffic ---------------------------------------------------------------------------

    def get(self, selector: Any, handler: Any = None, *, timeout: float | None = None, payload: Any = None,
            consolidation: Any = None, **options: Any) -> Replies:
        """Ask every queryable matching ``selector``; iterate the result for the replies (module ``query``)."""
        check_options(options, GET_OPTIONS)
        self.check_can_wait("get", handler)
        wait_s = DEFAULT_QUERY_TIMEOUT_S if timeout is None else float(timeout)
        body = None if payload is None else to_zbytes(payload)
        return self.fabric.query(to_key(selector), body, wait_s, hold_latest=consolidation not in IMMEDIATE)

    def put(self, key_expr: Any, payload: Any, **options: Any) -> None:
        """Publish ``payload`` on ``key_expr`` to every matching subscriber."""
        check_options(options, PUT_OPTIONS)
        self._check_open()
        self.fabric.publish(Sample(to_key(key_expr), to_zbytes(payload), zenoh.SampleKind.PUT))

    def check_can_wait(self, what: str, handler: Any) -> None:
        """Refuse a query on a closed session, from a callback, or with a handler of its own."""
        self._check_open()
        if handler is not None:
            raise TypeError(f"the memory fabric's {what} returns its replies; it takes no handler")
        if self.fabric.dispatcher.on_thread():
            raise BlockedCallback(f"{what} called from a callback: a callback never waits on the fabric (it would "
                                  f"wait for itself here); hand the work to a worker thread")

    def _check_open(self) -> None:
        if self._closed:
            raise zenoh.ZError("session closed")

    # --- life cycle -------------------------------------------------------------------------

    def close(self) -> None:
        """Undeclare everything this session declared (its tokens go: subscribers see them leave)."""
        if self._closed:
            return
        self._closed = True
        for entity in list(reversed(self._declared)):
            entity.undeclare()
        self.fabric.forget_session(self)

    def __enter__(self) -> MemorySession:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
