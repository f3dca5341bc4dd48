"""The two ways the memory fabric hands things over: a FIFO channel a worker reads, and the one callback thread.

A queryable or subscriber declared with ``zenoh.handlers.FifoChannel`` (or no handler) gets a :class:`Channel`:
``recv``, ``try_recv`` and iteration as on Zenoh's, iteration ending once the entity is undeclared and the
channel emptied. One declared with a callback has it run on the fabric's :class:`Dispatcher` thread, never on
the thread that put or asked: as in Zenoh, a callback runs in the transport's own thread, one at a time here
(so a test is deterministic, and a callback that blocks holds up the whole fabric, as rule 5 warns).
"""
from __future__ import annotations

import logging
import queue
import threading
from collections import deque
from collections.abc import Callable
from typing import Generic, TypeVar

import zenoh

__all__ = ["Channel", "Dispatcher"]

log = logging.getLogger("fabric.wire.memory")
T = TypeVar("T")


class Channel(Generic[T]):
    """A FIFO of queries or samples for one declared entity; closed when the entity is undeclared."""

    def __init__(self) -> None:
        self._items: deque[T] = deque()
        self._cond = threading.Condition()
        self._closed = False

    def put(self, item: T) -> bool:
        """Append ``item``; False (and nothing appended) once the channel is closed."""
        with self._cond:
            if self._closed:
                return False
            self._items.append(item)
            self._cond.notify()
            return True

    def recv(self) -> T:
        """The next item, waiting for it; ``zenoh.ZError`` once the channel is closed and empty."""
        with self._cond:
            self._cond.wait_for(lambda: bool(self._items) or self._closed)
            if self._items:
                return self._items.popleft()
        raise zenoh.ZError("the channel is closed: its entity was undeclared")

    def try_recv(self) -> T | None:
        """The next item, or None when there is none now."""
        with self._cond:
            return self._items.popleft() if self._items else None

    def __iter__(self) -> Channel[T]:
        return self

    def __next__(self) -> T:
        try:
            return self.recv()
        except zenoh.ZError:
            raise StopIteration from None

    def close(self) -> None:
        """No more items: readers take what is left, then their iteration ends."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()


class Dispatcher:
    """The fabric's callback thread: runs what it is given in order, logging (and keeping) a callback's error."""

    def __init__(self, name: str) -> None:
        self._todo: queue.SimpleQueue[tuple[Callable[..., object], tuple[object, ...]] | None] = queue.SimpleQueue()
        self.errors: list[BaseException] = []     # what callbacks raised (Zenoh logs them and carries on)
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def on_thread(self) -> bool:
        """Whether the caller is a callback running on this dispatcher."""
        return threading.current_thread() is self._thread

    def call_soon(self, fn: Callable[..., object], *args: object) -> None:
        """Run ``fn(*args)`` on the dispatcher thread after everything given before it."""
        self._todo.put((fn, args))

    def drain(self, timeout_s: float) -> bool:
        """Wait until everything given so far has run; False when it had not after ``timeout_s``."""
        if self.on_thread():
            raise RuntimeError("drain() called from a callback: it would wait for itself")
        done = threading.Event()
        self.call_soon(done.set)
        return done.wait(timeout_s)

    def close(self, timeout_s: float = 5.0) -> None:
        """Run what is queued, then stop the thread."""
        self._todo.put(None)
        if not self.on_thread():
            self._thread.join(timeout_s)

    def _run(self) -> None:
        while True:
            item = self._todo.get()
            if item is None:
                return
            fn, args = item
            try:
                fn(*args)
            except Exception as exc:
                log.exception("callback error in %s", getattr(fn, "__qualname__", fn))
                self.errors.append(exc)
            del item, fn, args        # drop the arguments now: a query no one keeps is finalized here
