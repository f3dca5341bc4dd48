"""Run one service as a process: open the session, start the service, stop on SIGTERM/SIGINT within a
deadline whatever the fabric's state, and say in one line why it cannot start.

Stopping. The first SIGTERM or SIGINT asks the service to stop and arms a deadline
(:data:`STOP_DEADLINE_S`): if closing has not finished by then (Zenoh's close waits some ten seconds
for a hub that is frozen or whose host went away), the process ends there, with the exit code it was
going to return; a second signal ends it at once. A thread woken by the signal (through the signal
wakeup fd) does this, so it works whatever the main thread is blocked in. Ending at the deadline
loses nothing: every store commits atomically, as after a kill. Started by ``fabric-cli up`` (which
sets ``FABRIC_LAUNCHER_PID``), the process also receives SIGTERM when the launcher dies, however it
dies (Linux ``PR_SET_PDEATHSIG``).

Exit codes, which the launcher acts on:

- 0: stopped as asked;
- 1: a bug (the traceback is in the log): the launcher restarts the service;
- 2: it cannot join the fabric, or another service of its role already serves the cell: a restart
  may succeed later, and the launcher restarts it with a growing pause;
- 78 (:data:`EXIT_NO_RESTART`, ``EX_CONFIG``): a restart cannot fix this: a damaged store, one
  written by a newer release, a bad cell configuration. The service logs one line naming the file
  and what to do, and leaves a note (``FABRIC_EXIT_NOTE``: JSON with ``service``, ``code``,
  ``message``, ``file``, ``reason``, ``doctor``) that the launcher turns into one line on its console.
"""
from __future__ import annotations

import argparse
import contextlib
import ctypes
import importlib
import json
import logging
import os
import signal
import sqlite3
import sys
import threading
import time
from pathlib import Path

import zenoh

from fabric.client.sessions import open_session
from fabric.services import SERVICE_MODULES
from fabric.signals import SignalEvents
from fabric.wire.config import SessionSettings
from fabric.wire.errors import ConfigError, FabricError, StoreError

__all__ = ["EXIT_CANNOT_JOIN", "EXIT_NO_RESTART", "EXIT_NOTE_ENV", "LAUNCHER_PID_ENV", "STOP_DEADLINE_S",
           "doctor_command", "serve", "setup_logging"]

EXIT_CANNOT_JOIN = 2
JOIN_WINDOW_S = 8.0               # how long a service retries a hub that refuses it (starting, or slow under load)
EXIT_NO_RESTART = 78              # EX_CONFIG (sysexits.h): the operator must act; a restart cannot fix this
STOP_DEADLINE_S = 3.5             # from the first SIGTERM/SIGINT to the end of the process, at the latest
EXIT_NOTE_ENV = "FABRIC_EXIT_NOTE"
LAUNCHER_PID_ENV = "FABRIC_LAUNCHER_PID"
_PR_SET_PDEATHSIG = 1


def setup_logging(name: str, level: str = "INFO") -> None:
    logging.basicConfig(level=getattr(logging, level.upper(), logging.INFO),
                        format=f"%(asctime)s {name} %(levelname)s %(message)s", datefmt="%H:%M:%S")


def doctor_command(cell: str, data_dir: str | Path | None) -> str:
    """The ``fabric-cli doctor`` command line that checks and repairs the stores of ``cell``."""
    return f"fabric-cli doctor --cell {cell}" + (f" --data-dir {data_dir}" if data_dir is not None else "")


def serve(name: str, settings: SessionSettings, options: argparse.Namespace,
          ready: threading.Event | None = None, stop: threading.Event | None = None) -> int:
    """Run service ``name`` until ``stop`` is set or a termination signal arrives; returns the exit code.

    In the main thread (a service process), signals are handled as the module docstring says; in
    another thread (a test running the service in-process), only ``stop`` ends it."""
    module = importlib.import_module(SERVICE_MODULES[name])
    stop = stop or threading.Event()
    log = logging.getLogger(f"fabric.{name}")
    guard: _StopGuard | None = None
    if threading.current_thread() is threading.main_thread():
        guard = _StopGuard(name, stop, log)
        guard.install()
        if not _die_with_launcher(log):
            return 0
    try:
        # a hub that is starting (its unit started with this one) or slow under load refuses a session the way
        # one that refuses these credentials does: tried again for a few seconds before saying why
        session = open_session(settings, JOIN_WINDOW_S)
    except FabricError as err:
        log.error("%s cannot join the fabric at %s: %s", name, ", ".join(settings.connect), err.message)
        return EXIT_CANNOT_JOIN
    code, svc = 0, None
    try:
        svc = module.build(session, settings.cell, options)
        svc.start()
        if ready is not None:
            ready.set()
        stop.wait()
    except (StoreError, ConfigError) as err:
        code = _cannot_start(name, settings.cell, options, err, log)
    except sqlite3.DatabaseError as exc:
        if getattr(exc, "sqlite_errorname", "") not in ("SQLITE_CORRUPT", "SQLITE_NOTADB"):
            raise
        # a store that does not name its file (all of them do, through fabric.store.sqlite): name the folder
        damaged = StoreError(f"a database of the {name} is damaged ({exc})", reason="damaged", problem=str(exc))
        code = _cannot_start(name, settings.cell, options, damaged, log)
    except FabricError as err:
        log.error("%s cannot start: %s", name, err.message)
        code = EXIT_CANNOT_JOIN
    except BaseException:
        code = 1                                     # a bug: its traceback follows; the launcher restarts it
        raise
    finally:
        if guard is not None:
            guard.code = code
            if code != 0:
                guard.arm()                          # closing after a failed start is bounded too
        _close(name, svc, session, log, guard)
    if code == 0:
        log.info("%s stopped", name)
    return code


def _cannot_start(name: str, cell: str, options: argparse.Namespace, err: FabricError, log: logging.Logger) -> int:
    """One line saying why ``name`` cannot start and what to do; the note for the launcher; the exit code."""
    data_dir = getattr(options, "data_dir", None)
    doctor = doctor_command(cell, data_dir)
    file, reason = str(err.details.get("file", "")), str(err.details.get("reason", ""))
    if isinstance(err, StoreError) and reason == "damaged":
        where = file or f"a database under {_service_dir(data_dir, cell, name)}"
        problem = err.details.get("problem")
        message = (f"{where} is damaged" + (f" ({problem})" if problem else "") + "; a restart cannot fix this: "
                   f"run '{doctor}' (it keeps a copy of the file and recovers what it can)")
    elif isinstance(err, StoreError):
        message = f"{err.message} (a restart cannot fix this; '{doctor}' says what it finds)"
    else:
        message = f"{err.message} (a restart cannot fix this)"
    log.error("%s cannot start: %s", name, message)
    _write_note({"service": name, "code": EXIT_NO_RESTART, "message": message, "file": file, "reason": reason,
                 "error": err.code, "doctor": doctor if isinstance(err, StoreError) else ""})
    return EXIT_NO_RESTART


def _service_dir(data_dir: str | None, cell: str, name: str) -> Path:
    from fabric.wire.config import service_data_dir
    return service_data_dir(data_dir, cell, name)


def _write_note(note: dict) -> None:
    """Leave ``note`` where the launcher asked (``FABRIC_EXIT_NOTE``), written whole or not at all."""
    path = os.environ.get(EXIT_NOTE_ENV)
    if not path:
        return
    tmp = f"{path}.{os.getpid()}.tmp"
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(note, fh)
        os.replace(tmp, path)
    except OSError:
        pass                        # the launcher then says what the exit code means, without the file


def _close(name: str, svc, session: zenoh.Session, log: logging.Logger, guard: _StopGuard | None) -> None:
    """Close the service and the session; an error while closing is one line, not a traceback."""
    for what, fn in (("the service", getattr(svc, "close", None)), ("the session", session.close)):
        if fn is None:
            continue
        if guard is not None:
            guard.step = f"closing {what}"
        try:
            fn()
        except Exception as exc:  # noqa: BLE001  (stopping goes on: logged in one line)
            log.warning("%s: closing %s failed: %s: %s", name, what, type(exc).__name__, exc)


def _die_with_launcher(log: logging.Logger) -> bool:
    """Started by ``fabric-cli up``: receive SIGTERM when the launcher dies (Linux). False when the
    launcher is already gone (it died before this process asked): do not start."""
    launcher = os.environ.get(LAUNCHER_PID_ENV)
    if not launcher:
        return True
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError):
        return True                 # not Linux: the launcher's process group still reaches this process
    if os.getppid() != int(launcher):
        log.warning("the launcher (pid %s) is gone: not starting", launcher)
        return False
    return True


class _StopGuard:
    """SIGTERM/SIGINT in a service process (see the module docstring). The C-level handler writes the
    signal's number to a socket; a thread reading it sets ``stop`` and arms the deadline, so neither
    depends on the main thread getting back to Python."""

    def __init__(self, name: str, stop: threading.Event, log: logging.Logger,
                 deadline_s: float = STOP_DEADLINE_S) -> None:
        self.name, self.stop, self.log, self.deadline_s = name, stop, log, deadline_s
        self.code = 0                 # what the process exits with if the deadline ends it
        self.step = "stopping"        # what it is doing (said if the deadline ends it)
        self._signals = 0
        self._armed = False
        self._lock = threading.Lock()

    def install(self) -> None:
        # the handlers take no lock (fabric.signals): a handler that set ``stop`` itself deadlocked under a
        # burst of signals (one ran between the bytecodes of ``stop.set()`` or of the main thread's
        # ``stop.wait()``, which hold the event's lock, and waited for that lock forever)
        SignalEvents(lambda sig: self._on_signal(sig.name), (signal.SIGTERM, signal.SIGINT)).install()
        previous = threading.excepthook

        def quiet_after_stop(args: threading.ExceptHookArgs) -> None:
            # a worker still running while the session closes fails on a closed publisher: one line
            if self.stop.is_set() and args.exc_type is not SystemExit:
                self.log.info("%s: thread %s ended at stop: %s: %s", self.name,
                              getattr(args.thread, "name", "?"), args.exc_type.__name__, args.exc_value)
            else:
                previous(args)

        threading.excepthook = quiet_after_stop

    def _on_signal(self, what: str) -> None:
        with self._lock:
            self._signals += 1
            first = self._signals == 1
        if first:
            self.log.info("%s: %s: stopping (within %g s)", self.name, what, self.deadline_s)
            self.arm()                  # the deadline first: nothing after it can keep the process alive
            self.stop.set()
        else:
            self.log.warning("%s: %s again: exiting now", self.name, what)
            self._exit()

    def arm(self) -> None:
        """End the process ``deadline_s`` from now if it has not ended by itself."""
        with self._lock:
            if self._armed:
                return
            self._armed = True
        end = time.monotonic() + self.deadline_s

        def at_deadline() -> None:
            time.sleep(max(0.0, end - time.monotonic()))
            self.log.warning("%s: still %s after %g s (the fabric does not answer): exiting now", self.name,
                             self.step, self.deadline_s)
            self._exit()

        threading.Thread(target=at_deadline, name=f"{self.name}:deadline", daemon=True).start()

    def _exit(self) -> None:
        for h in logging.getLogger().handlers:
            with contextlib.suppress(Exception):
                h.flush()
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        os._exit(self.code)
