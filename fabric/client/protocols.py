"""What the client's helpers need of a client: two methods, so they never import the Client back.

:mod:`fabric.client.job_waits`, :mod:`fabric.client.transfers` and
:mod:`fabric.client.follow` are written against :class:`Caller`: ``call`` (one
endpoint, one typed reply) and ``subscribe`` (one topic's decoded messages).
:class:`fabric.client.Client` is one; so is a stand-in in a test.
"""
from __future__ import annotations

from typing import Any, Protocol

__all__ = ["Caller", "Stream"]


class Stream(Protocol):
    """Decoded messages of one topic (``Client.subscribe``'s :class:`~fabric.client.subscriptions.Subscription`)."""

    def get(self, timeout: float | None = None) -> Any:
        """The next message; ``queue.Empty`` after ``timeout``."""
        ...

    def close(self) -> None:
        """Stop receiving."""
        ...


class Caller(Protocol):
    """Calls endpoints and subscribes to topics of one cell."""

    def call(self, service: str, command: str, request: Any = None, timeout: float | None = None) -> Any:
        """Ask ``service/command`` with ``request`` (None: the empty request); the typed reply, or the typed error
        raised."""
        ...

    def subscribe(self, service: str, topic: str) -> Stream:
        """The decoded messages of ``service/topic`` from now on."""
        ...
