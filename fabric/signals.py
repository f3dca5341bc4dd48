"""Setting a ``threading.Event`` on a signal without deadlock.

A Python signal handler runs in the main thread between two bytecodes, also
between those of ``Event.set()`` or of the main thread's own ``Event.wait()``,
which hold the event's lock (a plain, non-reentrant lock). A handler that
calls ``set()`` there waits for that lock forever: a burst of signals (Ctrl-C
twice, a terminal's SIGHUP after a SIGINT, a launcher's SIGTERM on top) could
freeze a process that was asked to stop. Starting a thread from the handler
is no way out: ``Thread.start()`` takes the threading module's own plain lock,
which a handler run inside the previous ``start()`` waits for forever (a hub
was found alive after a burst of 300 signals).

So the handler takes no lock at all. Python's C-level handler writes the
signal's number to a socket (``signal.set_wakeup_fd``); a watcher thread,
started before the handlers are installed, reads it and sets the event. The
Python-level handler does nothing. This is how every service process handles
its signals too (``fabric.services.host``).
"""
from __future__ import annotations

import signal
import socket
import threading
from collections.abc import Callable, Iterable

__all__ = ["SignalEvents", "on_signals"]


def _noted(_signum: int, _frame: object) -> None:
    """The Python-level handler: nothing (the watcher thread acts; module docstring)."""


class SignalEvents:
    """Each of ``signals`` calls ``act(signal)`` on a watcher thread (module docstring)."""

    def __init__(self, act: Callable[[signal.Signals], None], signals: Iterable[signal.Signals]) -> None:
        self.act = act
        self.signals = tuple(signals)
        self._r, self._w = socket.socketpair()
        self._w.setblocking(False)
        self._previous: dict[signal.Signals, object] = {}
        self._previous_fd = -1

    def install(self) -> SignalEvents:
        threading.Thread(target=self._watch, name="signals", daemon=True).start()
        for sig in self.signals:
            self._previous[sig] = signal.signal(sig, _noted)
        self._previous_fd = signal.set_wakeup_fd(self._w.fileno(), warn_on_full_buffer=False)
        return self

    def close(self) -> None:
        """Put back the handlers and the wakeup fd found at :meth:`install` (tests; a process just exits)."""
        signal.set_wakeup_fd(self._previous_fd)
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)  # type: ignore[arg-type]
        self._w.close()                  # the watcher reads the end of the stream and returns

    def _watch(self) -> None:
        wanted = {int(s) for s in self.signals}
        while True:
            try:
                data = self._r.recv(64)
            except OSError:
                return
            if not data:
                self._r.close()
                return
            for signum in data:
                if signum in wanted:
                    self.act(signal.Signals(signum))


def on_signals(choose: Callable[[], threading.Event],
               signals: Iterable[signal.Signals] = (signal.SIGTERM, signal.SIGINT)) -> SignalEvents:
    """Handle ``signals`` (main thread only) by setting the event ``choose()`` names at each signal (e.g. a
    stop the first time, a hurry the second), from a watcher thread (module docstring)."""
    return SignalEvents(lambda _sig: choose().set(), signals).install()
