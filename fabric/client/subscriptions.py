"""Subscriptions of the client: decoded telemetry of one topic, and liveliness changes of a cell's services.

The Zenoh callbacks only enqueue (or, for liveliness, parse the key and hand
the change on); decoding and validation happen in the reading thread.
"""
from __future__ import annotations

import queue
from collections.abc import Callable, Iterator
from typing import Any

import zenoh

from fabric.wire import codec
from fabric.wire.keys import parse_alive

__all__ = ["Subscription", "AliveSubscription"]


class Subscription:
    """Decoded messages of one topic; the Zenoh callback only enqueues bytes."""

    def __init__(self, session: zenoh.Session, key: str, msg_type: type, maxsize: int = 100_000) -> None:
        self.msg_type = msg_type
        self.dropped = 0
        self._q: queue.Queue[bytes] = queue.Queue(maxsize)
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            self._q.put_nowait(sample.payload.to_bytes())
        except queue.Full:
            self.dropped += 1  # counted; the consumer can see it fell behind

    def get(self, timeout: float | None = None) -> Any:
        """The next message (decoded and validated); ``queue.Empty`` after ``timeout``."""
        return codec.decode(self._q.get(timeout=timeout), self.msg_type)

    def __iter__(self) -> Iterator[Any]:
        while True:
            yield self.get()

    def close(self) -> None:
        self._sub.undeclare()


class AliveSubscription:
    """Liveliness changes of the cell's services: ``get()`` returns ``(service, alive)``.

    The Zenoh callback only parses the key (``keys.parse_alive``) and enqueues, or hands the change
    to ``on_change`` when one is given (it runs inside the Zenoh callback: it must not block, e.g.
    post a message to a UI). Changes are hints; the truth at any moment is :meth:`Client.alive`."""

    def __init__(self, session: zenoh.Session, key: str,
                 on_change: Callable[[str, bool], None] | None = None) -> None:
        self._q: queue.Queue[tuple[str, bool]] = queue.Queue()
        self._on_change = on_change
        self._sub = session.liveliness().declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        change = (parse_alive(str(sample.key_expr))[1], sample.kind == zenoh.SampleKind.PUT)
        if self._on_change is not None:
            self._on_change(*change)
        else:
            self._q.put(change)

    def get(self, timeout: float | None = None) -> tuple[str, bool]:
        """The next change; ``queue.Empty`` after ``timeout``."""
        return self._q.get(timeout=timeout)

    def close(self) -> None:
        self._sub.undeclare()
