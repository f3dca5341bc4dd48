"""What a memory session declares: queryables, subscribers, publishers and liveliness tokens.

Each is what Zenoh's declaration returns, reduced to what the fabric's code uses: ``undeclare``, and for a
queryable or subscriber declared without a callback, ``recv``, ``try_recv`` and iteration (see
:class:`~fabric.wire.memory.channel.Channel`). A callback is run on the fabric's dispatcher thread.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import zenoh

from fabric.wire.memory.channel import Channel
from fabric.wire.memory.query import MemoryQuery, Sample, check_options, to_key, to_zbytes

if TYPE_CHECKING:
    from fabric.wire.memory.session import MemorySession

__all__ = ["MemoryQueryable", "MemorySubscriber", "MemoryPublisher", "MemoryToken", "callback_of",
           "PUT_OPTIONS"]

PUT_OPTIONS = {"encoding", "congestion_control", "priority", "express", "attachment", "timestamp",
               "reliability", "allowed_destination"}


def callback_of(handler: Any) -> Callable[[Any], Any] | None:
    """The callback of a declaration's ``handler``, or None for a channel (``zenoh.handlers.FifoChannel``, or no
    handler: Zenoh's default is a FIFO channel too). Other handlers are not served by the memory fabric."""
    if handler is None or isinstance(handler, (zenoh.handlers.FifoChannel, zenoh.handlers.DefaultHandler)):
        return None
    if callable(handler):
        return handler
    raise TypeError(f"the memory fabric takes a callback or zenoh.handlers.FifoChannel, not {type(handler).__name__}")


class _Receiver:
    """A declared entity that receives items: through its callback, or into its channel."""

    def __init__(self, session: MemorySession, key_expr: Any, handler: Any) -> None:
        self.session = session
        self.key_expr = to_key(key_expr)
        self.callback = callback_of(handler)
        self.channel: Channel[Any] = Channel()
        self.undeclared = False

    def recv(self) -> Any:
        """The next item of a channel (waits); ``zenoh.ZError`` once undeclared and emptied."""
        self._need_channel()
        return self.channel.recv()

    def try_recv(self) -> Any:
        """The next item of a channel, or None."""
        self._need_channel()
        return self.channel.try_recv()

    def __iter__(self) -> Channel[Any]:
        self._need_channel()
        return self.channel

    def _need_channel(self) -> None:
        if self.callback is not None:
            raise zenoh.ZError(f"{self.key_expr} was declared with a callback: it has no channel to read")

    def undeclare(self) -> None:
        """Stop receiving; a channel's readers take what is left, then their iteration ends."""
        if not self.undeclared:
            self.undeclared = True
            self.session.forget(self)
            self.channel.close()


class MemoryQueryable(_Receiver):
    """A declared queryable: its queries go to its callback or its channel."""

    def offer(self, query: MemoryQuery) -> None:
        """Take ``query`` (a callback runs on the dispatcher; an undeclared queryable drops it unanswered)."""
        if self.callback is not None:
            self.session.fabric.dispatcher.call_soon(self._answer, query)
        elif not self.channel.put(query):
            query.drop()

    def _answer(self, query: MemoryQuery) -> None:
        callback = self.callback
        if callback is None or self.undeclared:
            query.drop()
            return
        try:
            callback(query)
        except BaseException:
            query.drop()                 # the error's traceback would keep the query, and the get, open
            raise


class MemorySubscriber(_Receiver):
    """A declared subscriber of samples, or (``liveliness``) of liveliness changes."""

    def __init__(self, session: MemorySession, key_expr: Any, handler: Any, liveliness: bool = False) -> None:
        super().__init__(session, key_expr, handler)
        self.liveliness = liveliness

    def offer(self, sample: Sample) -> None:
        """Take ``sample`` (a callback runs on the dispatcher)."""
        if self.callback is not None:
            self.session.fabric.dispatcher.call_soon(self._receive, sample)
        else:
            self.channel.put(sample)

    def _receive(self, sample: Sample) -> None:
        callback = self.callback
        if callback is not None and not self.undeclared:
            callback(sample)


class MemoryPublisher:
    """A declared publisher: ``put`` sends to every subscriber whose key intersects its own."""

    def __init__(self, session: MemorySession, key_expr: Any, options: dict[str, Any]) -> None:
        check_options(options, PUT_OPTIONS)
        self.session = session
        self.key_expr = to_key(key_expr)
        self.undeclared = False

    def put(self, payload: Any, **options: Any) -> None:
        """Publish ``payload``; ``zenoh.ZError`` once undeclared or its session closed."""
        check_options(options, PUT_OPTIONS)
        if self.undeclared:
            raise zenoh.ZError(f"the publisher of {self.key_expr} was undeclared")
        self.session.put(self.key_expr, payload)

    def undeclare(self) -> None:
        """Stop publishing."""
        if not self.undeclared:
            self.undeclared = True
            self.session.forget(self)


class MemoryToken:
    """A declared liveliness token: present until undeclared or its session closes."""

    def __init__(self, session: MemorySession, key_expr: Any) -> None:
        self.session = session
        self.key_expr = to_key(key_expr)
        self.undeclared = False

    def sample(self, kind: zenoh.SampleKind) -> Sample:
        """The liveliness sample of this token appearing (``PUT``) or going (``DELETE``)."""
        return Sample(self.key_expr, to_zbytes(b""), kind)

    def undeclare(self) -> None:
        """The token goes: liveliness subscribers see a ``DELETE``."""
        if not self.undeclared:
            self.undeclared = True
            self.session.forget(self)
