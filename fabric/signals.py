"""Setting a ``threading.Event`` from a signal handler without deadlock.

A Python signal handler runs in the main thread between two bytecodes, also
between those of ``Event.set()`` or of the main thread's own ``Event.wait()``,
which hold the event's lock (a plain, non-reentrant lock). A handler that
calls ``set()`` there waits for that lock forever: a burst of signals (Ctrl-C
twice, a terminal's SIGHUP after a SIGINT, a launcher's SIGTERM on top) could
freeze a process that was asked to stop. The handlers here set events from a
short-lived thread instead, which takes the lock once the main thread has let
go of it.
"""
from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterable

__all__ = ["set_from_handler", "on_signals"]


def set_from_handler(event: threading.Event) -> None:
    """``event.set()``, safe inside a signal handler (module docstring)."""
    threading.Thread(target=event.set, name="signal-set", daemon=True).start()


def on_signals(choose: Callable[[], threading.Event],
               signals: Iterable[signal.Signals] = (signal.SIGTERM, signal.SIGINT)) -> None:
    """Handle ``signals`` (main thread only) by setting the event ``choose()`` names at each signal (e.g. a
    stop the first time, a hurry the second), from a thread (module docstring)."""
    for sig in signals:
        signal.signal(sig, lambda *_: set_from_handler(choose()))
