"""``fabric-cli up``: host the fabric hub and run every service as its own supervised process on one host.

The children run in one process group of their own (so Ctrl-C in the terminal
reaches only the launcher, which stops a running print first) and die with
the launcher even if it is killed (``PR_SET_PDEATHSIG``). A child that exits
is reported and restarted with a growing pause (0.5 s, doubling up to 30 s;
back to 0.5 s once it has run for a minute). With ``--listen`` the hub
listens there and the children connect there; with ``--connect`` (and
``--no-hub``) they join a hub elsewhere. With ``--secure DIR`` the hub
enforces TLS, passwords and roles (``fabric.security``) and every service
joins it as a client with the services' credentials.
"""
from __future__ import annotations

import contextlib
import ctypes
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import zenoh

from fabric.client import Client
from fabric.security.credentials import Credentials
from fabric.security.hub import hub_zenoh_config, role_settings
from fabric.wire.config import SessionSettings, zenoh_config
from fabric.wire.errors import FabricError, ServiceUnavailable
from fabric.wire.keys import SERVICES, Keys

__all__ = ["CellProcesses", "hub_settings", "run_up"]

BACKOFF_FIRST_S = 0.5
BACKOFF_MAX_S = 30.0
HEALTHY_AFTER_S = 60.0
STOP_PRINT_WAIT_S = 30.0
_PR_SET_PDEATHSIG = 1


def hub_settings(settings: SessionSettings) -> SessionSettings:
    """The router session that hosts the hub endpoint the services connect to."""
    return replace(settings, mode="router", listen=list(settings.listen or settings.connect), connect=[])


def _die_with_parent() -> None:
    """In the child, before exec: receive SIGTERM when the launcher dies (Linux)."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass                       # not Linux: the process group still lets the launcher stop them


def _child_setup(pgid: int) -> Callable[[], None]:
    """In the child, before exec: join process group ``pgid`` (0: a new group led by the child) and die
    with the launcher. (Popen's own ``process_group`` argument needs Python 3.11.)"""

    def setup() -> None:
        os.setpgid(0, pgid)
        _die_with_parent()

    return setup


@dataclass
class _Child:
    """One supervised service: its process, restarts and when it may be started again."""

    name: str
    proc: subprocess.Popen
    started_s: float
    restarts: int = 0
    backoff_s: float = BACKOFF_FIRST_S
    due_s: float | None = None     # restart planned at this monotonic time
    codes: list[int] = field(default_factory=list)


class CellProcesses:
    """The five service processes of one cell (plus the hub), started, supervised and stopped together.

    (Not the cell *model*, ``fabric.robot.cell.Cell``: this is the set of running processes.)"""

    def __init__(self, settings: SessionSettings, services: tuple[str, ...] = SERVICES, host_hub: bool = True,
                 log_dir: Path | None = None, extra_args: dict[str, list[str]] | None = None,
                 data_dir: Path | None = None, secure: Credentials | None = None) -> None:
        self.services, self.host_hub = services, host_hub
        self.log_dir, self.extra_args, self.data_dir = log_dir, extra_args or {}, data_dir
        self.secure = secure
        if secure is None:
            # the hub listens on --listen (else on the --connect endpoint); everyone else connects there
            self.hub_listen = list(settings.listen or settings.connect)
            hub_eps = self.hub_listen if host_hub else list(settings.connect)
            self.settings = replace(settings, connect=hub_eps, listen=[])
            self.client_settings = self.settings
        else:
            # secured: the hub listens on TLS (--listen, else where hub.json5 says); services join as clients
            # with the services' credentials, this launcher with the operator's
            self.hub_listen = list(settings.listen) or secure.listen_endpoints()
            self.settings = role_settings(secure, settings, "service")
            self.client_settings = role_settings(secure, settings, "operator")
        self.children: dict[str, _Child] = {}
        self.hub: zenoh.Session | None = None
        self._pgid: int | None = None

    @property
    def procs(self) -> dict[str, subprocess.Popen]:
        """The current process of each service."""
        return {name: c.proc for name, c in self.children.items()}

    def start(self, deadline_s: float = 60.0) -> None:
        """Host the hub, start every service and wait until all are alive (or stop them all)."""
        self.launch()
        self.wait_up(deadline_s)

    def launch(self) -> None:
        """Host the hub and start every service, without waiting (several cells start side by side). Call it
        from a thread that outlives the services: the kernel signals them when the thread that started them
        ends (``PR_SET_PDEATHSIG`` follows the thread, not the process)."""
        if self.host_hub:
            self.hub = zenoh.open(self._hub_config())
        for name in self.services:
            self.children[name] = _Child(name, self._spawn(name), time.monotonic())

    def wait_up(self, deadline_s: float = 60.0) -> None:
        """Wait until every service is alive; if one is not by ``deadline_s``, stop them all and raise."""
        try:
            with Client.connect(self.client_settings) as client:
                client.wait_alive(self.services, deadline_s)
        except (ServiceUnavailable, OSError) as exc:
            dead = {n: c.proc.poll() for n, c in self.children.items() if c.proc.poll() is not None}
            self.stop()
            raise ServiceUnavailable(f"services did not come up within {deadline_s:g} s ({exc}); exited: {dead}",
                                     exited=dead) from None

    def _hub_config(self) -> zenoh.Config:
        if self.secure is None:
            return zenoh_config(hub_settings(self.settings))
        return hub_zenoh_config(self.secure, self.settings, self.hub_listen)

    def _spawn(self, name: str) -> subprocess.Popen:
        cmd = [sys.executable, "-m", "fabric.cli.main", "serve", name, *self.settings.to_args()]
        if self.data_dir is not None:
            cmd += ["--data-dir", str(self.data_dir)]
        cmd += self.extra_args.get(name, [])
        log = None
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            log = self.log_dir / f"{name}.log"
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        # the child writes to its own copy of the log file; the launcher's is closed once it is started
        with open(log, "ab") if log is not None else contextlib.nullcontext() as out:
            try:
                proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT if out else None, env=env,
                                        preexec_fn=_child_setup(self._pgid or 0))
            except (PermissionError, subprocess.SubprocessError):
                # the group is gone (all its members exited): start a new one
                proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT if out else None, env=env,
                                        preexec_fn=_child_setup(0))
                self._pgid = proc.pid
        if self._pgid is None:
            self._pgid = proc.pid
        return proc

    def respawn(self, name: str) -> subprocess.Popen:
        """Start service ``name`` again now (its previous process has exited)."""
        c = self.children[name]
        c.proc, c.started_s, c.due_s = self._spawn(name), time.monotonic(), None
        return c.proc

    def supervise(self, say=print) -> bool:
        """Report children that exited, and restart them when their pause is over; True if any died."""
        died = False
        now = time.monotonic()
        for c in self.children.values():
            code = c.proc.poll()
            if code is not None and c.due_s is None:
                died = True
                if now - c.started_s >= HEALTHY_AFTER_S:
                    c.backoff_s = BACKOFF_FIRST_S
                c.codes.append(code)
                c.due_s = now + c.backoff_s
                say(f"!! service {c.name} exited with code {code}; restarting it in {c.backoff_s:g} s"
                    + (f" (see {self.log_dir / (c.name + '.log')})" if self.log_dir else ""))
            elif c.due_s is not None and now >= c.due_s:
                c.proc, c.started_s, c.due_s = self._spawn(c.name), now, None
                c.restarts += 1
                c.backoff_s = min(c.backoff_s * 2.0, BACKOFF_MAX_S)
                say(f"   service {c.name} restarted (pid {c.proc.pid}, restart {c.restarts})")
        return died

    def stop(self, grace_s: float = 10.0) -> None:
        """SIGTERM to every child (the group), then SIGKILL to those still running after ``grace_s``."""
        for c in self.children.values():
            if c.proc.poll() is None:
                c.proc.send_signal(signal.SIGTERM)
        if self._pgid is not None:
            try:
                os.killpg(self._pgid, signal.SIGTERM)
            except ProcessLookupError:
                pass                    # every member has already exited
        end = time.monotonic() + grace_s
        for c in self.children.values():
            try:
                c.proc.wait(timeout=max(0.1, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                c.proc.kill()
                c.proc.wait()
        if self.hub is not None:
            self.hub.close()
            self.hub = None


def stop_print_first(settings: SessionSettings, say=print, wait_s: float = STOP_PRINT_WAIT_S) -> None:
    """Before the cell goes down: a print in progress is stopped cleanly (``stopped`` recorded)."""
    try:
        with Client.connect(settings) as client:
            state = client.state().state
            if state not in ("printing", "paused"):
                return
            events = client.subscribe("station", "events")
            try:
                client.stop()
                end = time.monotonic() + wait_s
                while time.monotonic() < end:
                    try:
                        ev = events.get(timeout=max(0.1, end - time.monotonic()))
                    except queue.Empty:
                        break
                    if ev.kind in ("stopped", "fault"):
                        say(f"   the print was {state}: stopped it at layer {ev.layer + 1} (recorded)")
                        return
                say(f"!! the print was {state}: asked it to stop, but saw no 'stopped' within {wait_s:g} s")
            finally:
                events.close()
    except FabricError as err:
        say(f"!! could not stop the print first ({err.code}: {err.message})")


def run_up(settings: SessionSettings, services: tuple[str, ...], host_hub: bool, log_dir: Path | None,
           extra_args: dict[str, list[str]], data_dir: Path | None = None, out=print,
           secure: Credentials | None = None) -> int:
    """Start the cell, report where it is, supervise until Ctrl-C, stop a running print, then stop everything."""
    cell = CellProcesses(settings, services, host_hub, log_dir, extra_args, data_dir, secure)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    t0 = time.monotonic()
    try:
        cell.start()
    except ServiceUnavailable as err:
        out(f"!! {err.message}")
        return 1
    hub = ", ".join(cell.settings.connect)
    out(f"cell '{settings.cell}' up in {time.monotonic() - t0:.1f} s; hub {hub if host_hub else '(external) ' + hub}"
        + (f" (TLS, passwords, roles: {secure.root})" if secure is not None else ""))
    keys = Keys(settings.cell)
    for name, p in cell.procs.items():
        out(f"  {name:<11} pid {p.pid:<7} {keys.cmd_all(name)}")
    out("Ctrl-C stops the print (if one runs), then every service.")
    rc = 0
    try:
        while not stop.wait(0.2):
            if cell.supervise(out):
                rc = 1
    finally:
        if "station" in services:
            stop_print_first(cell.client_settings, out)
        out("stopping services ...")
        cell.stop()
    return rc
