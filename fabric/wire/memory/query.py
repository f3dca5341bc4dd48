"""The query side of the memory fabric: what a queryable receives, and what ``get`` returns, as Zenoh has them.

A ``get`` makes one :class:`MemoryQuery` per matching queryable and returns :class:`Replies`, which its caller
iterates. As in Zenoh (measured against zenoh 1.10 on one session):

- a reply arrives as soon as it is sent when the get asked for no consolidation (``ConsolidationMode.NONE``:
  every command, :mod:`fabric.wire.qos`); otherwise (the default, ``LATEST``) the last reply per key is held
  until every query of the get is finalized. An error reply is handed over at once;
- a query is finalized when it is dropped: ``with query:`` left, ``query.drop()``, or the last reference to it
  gone (a callback that keeps none);
- the iteration ends when every query is finalized; at the get's timeout the held replies come, then an error
  reply ``Timeout``, and later replies are dropped;
- a reply on a key that does not intersect the query's, or to a finalized query, raises ``zenoh.ZError``.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import zenoh

__all__ = ["Sample", "ReplyError", "Reply", "MemoryQuery", "Replies", "to_zbytes", "to_key", "check_options"]

TIMEOUT_PAYLOAD = b"Timeout"      # what Zenoh answers a get whose queryables did not all finish in time
REPLY_OPTIONS = {"encoding", "congestion_control", "priority", "express", "attachment", "timestamp"}


def check_options(options: dict[str, Any], known: set[str]) -> None:
    """A keyword Zenoh does not take is a TypeError here too (a misspelt option fails in the fast tier)."""
    unknown = sorted(set(options) - known)
    if unknown:
        raise TypeError(f"unexpected keyword argument(s) {', '.join(unknown)} (takes {', '.join(sorted(known))})")


def to_zbytes(payload: Any) -> zenoh.ZBytes:
    """A payload as Zenoh carries it (``bytes``, ``bytearray``, ``str`` or ``ZBytes``)."""
    if isinstance(payload, zenoh.ZBytes):
        return payload
    if isinstance(payload, (bytes, bytearray, memoryview)):
        return zenoh.ZBytes(bytes(payload))
    if isinstance(payload, str):
        return zenoh.ZBytes(payload)
    raise TypeError(f"a payload is bytes, str or zenoh.ZBytes, not {type(payload).__name__}")


def to_key(key_expr: Any) -> zenoh.KeyExpr:
    """A key expression, checked as Zenoh checks it (``zenoh.ZError`` for ``a//b``, a trailing slash...)."""
    return zenoh.KeyExpr(str(key_expr))


@dataclass(frozen=True)
class Sample:
    """A published value, a liveliness change or a successful reply (``Reply.ok``)."""

    key_expr: zenoh.KeyExpr
    payload: zenoh.ZBytes
    kind: zenoh.SampleKind


@dataclass(frozen=True)
class ReplyError:
    """An error reply (``Reply.err``): a queryable's ``reply_err`` or Zenoh's own ``Timeout``."""

    payload: zenoh.ZBytes


@dataclass(frozen=True)
class Reply:
    """One reply of a get: ``ok`` or ``err`` is set."""

    ok: Sample | None = None
    err: ReplyError | None = None


class Replies:
    """What ``get`` returns: iterate it for the replies; it ends when every query is finalized, or at the
    timeout (after an error reply ``Timeout``)."""

    def __init__(self, timeout_s: float, hold_latest: bool) -> None:
        self._cond = threading.Condition(threading.RLock())     # RLock: a query may be finalized while held
        self._ready: deque[Reply] = deque()
        self._held: dict[str, Reply] = {}                         # LATEST consolidation: last reply per key
        self._hold_latest = hold_latest
        self._open = 0                                            # queries not finalized yet
        self._deadline = time.monotonic() + timeout_s
        self._ended = False

    @classmethod
    def of(cls, replies: list[Reply]) -> Replies:
        """Replies known at once (a liveliness query: the fabric knows every token)."""
        got = cls(0.0, hold_latest=False)
        got._ready.extend(replies)
        got._ended = True
        return got

    def opened(self) -> None:
        """A query of this get was handed to a queryable."""
        with self._cond:
            self._open += 1

    def deliver(self, reply: Reply) -> None:
        """A queryable's reply (dropped when the get already ended: it timed out)."""
        with self._cond:
            if self._ended:
                return
            if reply.ok is not None and self._hold_latest:
                self._held[str(reply.ok.key_expr)] = reply
            else:
                self._ready.append(reply)
            self._cond.notify_all()

    def finalized(self) -> None:
        """A query of this get was finalized: the last one ends the get."""
        with self._cond:
            self._open -= 1
            if self._open <= 0 and not self._ended:
                self._end()

    def _end(self) -> None:
        self._ready.extend(self._held.values())
        self._held.clear()
        self._ended = True
        self._cond.notify_all()

    def __iter__(self) -> Replies:
        return self

    def __next__(self) -> Reply:
        with self._cond:
            while True:
                if self._ready:
                    return self._ready.popleft()
                if self._ended:
                    raise StopIteration
                left = self._deadline - time.monotonic()
                if left <= 0:
                    self._end()
                    self._ready.append(Reply(err=ReplyError(to_zbytes(TIMEOUT_PAYLOAD))))
                    continue
                self._cond.wait(left)


class MemoryQuery:
    """A query as a queryable receives it: ``key_expr``, ``payload``, ``reply``, ``reply_err``, ``drop``, and a
    context manager that finalizes it on exit."""

    def __init__(self, key_expr: zenoh.KeyExpr, payload: zenoh.ZBytes | None, replies: Replies) -> None:
        self._key_expr = key_expr
        self._payload = payload
        self._replies = replies
        self._lock = threading.Lock()
        self._finalized = False
        replies.opened()

    @property
    def key_expr(self) -> zenoh.KeyExpr:
        """The key expression asked (it may hold wildcards)."""
        return self._key_expr

    @property
    def payload(self) -> zenoh.ZBytes | None:
        """The request's payload; None when the get sent none."""
        return self._payload

    def reply(self, key_expr: Any, payload: Any, **options: Any) -> None:
        """Answer with ``payload`` on ``key_expr`` (which must intersect the query's); ``options`` as Zenoh's
        (``express``, ``priority``...: accepted, no effect in memory)."""
        check_options(options, REPLY_OPTIONS)
        key = to_key(key_expr)
        if not key.intersects(self._key_expr):
            raise zenoh.ZError(f"Attempted to reply on `{key}`, which does not intersect with query "
                               f"`{self._key_expr}`, despite query only allowing replies on matching key expressions")
        self._send(Reply(ok=Sample(key, to_zbytes(payload), zenoh.SampleKind.PUT)))

    def reply_err(self, payload: Any, **options: Any) -> None:
        """Answer with an error reply carrying ``payload``."""
        check_options(options, {"encoding"})
        self._send(Reply(err=ReplyError(to_zbytes(payload))))

    def _send(self, reply: Reply) -> None:
        with self._lock:
            if self._finalized:
                raise zenoh.ZError("Dropped query")
        self._replies.deliver(reply)

    def drop(self) -> None:
        """Finalize the query: no more replies; the get ends once all its queries are finalized."""
        with self._lock:
            if self._finalized:
                return
            self._finalized = True
        self._replies.finalized()

    def __enter__(self) -> MemoryQuery:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.drop()

    def __del__(self) -> None:
        self.drop()

