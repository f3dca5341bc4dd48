"""One writer per service: every state change runs as a step on one thread, in the order it was asked.

This is the single-reactor model of Klipper (``klippy/reactor.py``) and
Moonraker: a command handler never changes the service's state itself. It asks
the writer to run a *step* (a plain function) and waits for its result; the
writer's thread runs the steps one at a time, so no two changes interleave and
no lock is needed around the state. A step must be short: work that takes time
or asks another service (a collision check, fetching an artifact) runs in the
handler's own thread between two steps, and the second step re-checks the state
the first one saw (compare-and-set, see :class:`Stale`) instead of writing from
a stale copy.

The thread that runs the steps belongs to the service: a plain service calls
:meth:`Writer.run` in a thread of its own; the station runs them between the
ticks of its simulation clock with :meth:`Writer.run_pending`, so the clock is
the same writer and the twin is touched by exactly one thread.

Which fields are the writer's is said in the code, not in comments: a service
declares them :class:`Owned` (a descriptor), and reading or changing one from
any other thread while the writer runs raises :class:`OwnershipError`. Before
the writer's thread first runs (the service being built) and once it is closed
(the service shutting down, its thread ended) the constructing or closing
thread may touch them.
"""
from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any, Generic, TypeVar, overload

from fabric.wire.errors import ServiceUnavailable, StateError

__all__ = ["Writer", "Stale", "Owned", "OwnershipError"]

T = TypeVar("T")
V = TypeVar("V")


class OwnershipError(RuntimeError):
    """A field only the writer may touch was touched by another thread (a bug: the change must be a step)."""


class Stale(StateError):
    """The state a long command started from changed before it could act (compare-and-set failed):
    nothing was done; the caller may ask again."""


class Writer:
    """A FIFO of steps run by one thread (see the module docstring)."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._steps: queue.SimpleQueue[tuple[Callable[[], Any], Future[Any]] | None] = queue.SimpleQueue()
        self._thread_id: int | None = None
        self._closed = threading.Event()

    # Asking for a step -----------------------------------------------------------------------

    def submit(self, step: Callable[[], T]) -> Future[T]:
        """Queue ``step``; its result (or exception) arrives in the returned future."""
        fut: Future[T] = Future()
        if self._closed.is_set():
            fut.set_exception(ServiceUnavailable(f"{self.name} is closing", service=self.name))
            return fut
        self._steps.put((step, fut))
        return fut

    def call(self, step: Callable[[], T], timeout_s: float = 30.0) -> T:
        """Run ``step`` on the writer and return its result (its exception is raised here). Called on the
        writer's own thread, the step runs at once (a step may call another)."""
        if self.on_writer() and not self._closed.is_set():
            return step()
        fut = self.submit(step)
        try:
            return fut.result(timeout=timeout_s)
        except FutureTimeout:
            if not fut.cancel():                 # already running: a step is short, take its outcome
                return fut.result()
            raise ServiceUnavailable(f"{self.name} did not get to the change within {timeout_s:g} s (busy or "
                                     f"stuck); nothing was done", service=self.name, timeout_s=timeout_s) from None

    def on_writer(self) -> bool:
        """Whether the calling thread is the writer's."""
        return self._thread_id == threading.get_ident()

    def require(self, what: str) -> None:
        """Raise :class:`OwnershipError` unless the calling thread may touch the writer's state (``what`` names
        it): the writer's own thread, or any thread before the writer first ran or after it closed."""
        owner = self._thread_id
        if owner is None or owner == threading.get_ident() or self._closed.is_set():
            return
        raise OwnershipError(f"{what} belongs to {self.name}'s writer, but thread "
                             f"{threading.current_thread().name!r} touched it outside a step")

    # Running the steps -------------------------------------------------------------------------

    def run_pending(self, wait_s: float) -> int:
        """Run the queued steps on the calling thread (which becomes the writer), waiting up to ``wait_s``
        for the first one; returns how many ran. The steps queued meanwhile run too, up to what was
        queued when the batch began, so a caller ticking a clock is not starved."""
        self._thread_id = threading.get_ident()
        try:
            item = self._steps.get(timeout=wait_s) if wait_s > 0 else self._steps.get_nowait()
        except queue.Empty:
            return 0
        ran = 0
        budget = self._steps.qsize() + 1
        while item is not None:
            ran += self._run(*item)
            budget -= 1
            if budget <= 0:
                break
            try:
                item = self._steps.get_nowait()
            except queue.Empty:
                break
        return ran

    def run(self, stop: threading.Event, wait_s: float = 0.5) -> None:
        """Run steps on the calling thread until ``stop`` is set (a service's writer thread)."""
        while not stop.is_set():
            self.run_pending(wait_s)

    def close(self) -> None:
        """Refuse new steps and fail those still queued (their callers get ``unavailable``)."""
        self._closed.set()
        while True:
            try:
                item = self._steps.get_nowait()
            except queue.Empty:
                return
            if item is not None and item[1].set_running_or_notify_cancel():    # its caller may have given up
                item[1].set_exception(ServiceUnavailable(f"{self.name} is closing", service=self.name))

    @staticmethod
    def _run(step: Callable[[], Any], fut: Future[Any]) -> bool:
        """Run one step unless its caller gave up on it (cancelled: it never runs); True when it ran."""
        if not fut.set_running_or_notify_cancel():
            return False
        try:
            fut.set_result(step())
        except BaseException as exc:  # noqa: BLE001 - handed to the caller, who answers or logs it
            fut.set_exception(exc)
        return True


class Owned(Generic[V]):
    """A field of a service that only its :class:`Writer` may read or change (the service's ``writer``
    attribute): declared on the class (``twin: Owned[Twin] = Owned()``), set and read as a plain attribute,
    checked on every access (:meth:`Writer.require`)."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name
        self.slot = f"_owned_{name}"

    @overload
    def __get__(self, obj: None, objtype: type | None = None) -> Owned[V]: ...

    @overload
    def __get__(self, obj: object, objtype: type | None = None) -> V: ...

    def __get__(self, obj: object | None, objtype: type | None = None) -> V | Owned[V]:
        if obj is None:
            return self
        obj.writer.require(f"{type(obj).__name__}.{self.name}")      # type: ignore[attr-defined]
        try:
            return obj.__dict__[self.slot]
        except KeyError:
            raise AttributeError(f"{type(obj).__name__}.{self.name} is not set yet") from None

    def __set__(self, obj: object, value: V) -> None:
        obj.writer.require(f"{type(obj).__name__}.{self.name}")      # type: ignore[attr-defined]
        obj.__dict__[self.slot] = value
