"""``fabric-cli up``: host the fabric hub and run every service as its own supervised process on one host.

Before it starts anything it makes sure it can: the hub's port must be free (else one line saying
which, and what to do), and the cell must not already be served on the hub (else one line naming the
services that serve it: nothing is started, nothing restarted in a loop).

The children run in one process group of their own (so Ctrl-C in the terminal reaches only the
launcher, which stops a running print first) and die with the launcher however it ends: it tells
them its pid (``FABRIC_LAUNCHER_PID``) and each asks the kernel for SIGTERM when it dies
(``PR_SET_PDEATHSIG``, in ``fabric.services.host``). A service stops within a few seconds of
SIGTERM whatever the fabric's state. A child that exits is reported and restarted with a growing
pause (0.5 s, doubling up to 30 s; back to 0.5 s once it has run for a minute), except one that exits
with :data:`~fabric.services.host.EXIT_NO_RESTART` (a damaged store, say): a restart cannot fix
that, so it says so in one line (which service, which file, what to do) and leaves it stopped while
the rest of the cell keeps running; once the file has been repaired (``fabric-cli doctor``) or moved
aside, it starts it again. With ``--listen`` the hub listens there and the children connect there;
with ``--connect`` (and ``--no-hub``) they join a hub elsewhere. With ``--secure DIR`` the hub
enforces TLS, passwords and roles (``fabric.security``) and every service joins it as a client with
the services' credentials.
"""
from __future__ import annotations

import contextlib
import fcntl
import json
import os
import queue
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import zenoh

from fabric.client import Client
from fabric.security.credentials import Credentials
from fabric.security.hub import hub_zenoh_config, role_settings
from fabric.services.host import EXIT_NO_RESTART, EXIT_NOTE_ENV, LAUNCHER_PID_ENV, STOP_DEADLINE_S
from fabric.signals import on_signals
from fabric.wire.config import SessionSettings, service_data_dir, zenoh_config
from fabric.wire.errors import ConfigError, FabricError, ServiceUnavailable, StateError
from fabric.wire.keys import SERVICES, Keys

__all__ = ["CellProcesses", "hub_settings", "run_up"]

BACKOFF_FIRST_S = 0.5
BACKOFF_MAX_S = 30.0
HEALTHY_AFTER_S = 60.0
STOP_PRINT_WAIT_S = 30.0
STOP_GRACE_S = STOP_DEADLINE_S + 4.0      # SIGTERM -> SIGKILL: a service ends within STOP_DEADLINE_S by itself
HUB_CLOSE_S = 3.0                         # closing the hub session waits no longer than this


def hub_settings(settings: SessionSettings) -> SessionSettings:
    """The router session that hosts the hub endpoint the services connect to."""
    return replace(settings, mode="router", listen=list(settings.listen or settings.connect), connect=[])


def _signature(path: Path) -> tuple[int, int, int] | None:
    """What changes when a file is replaced, rewritten or removed (None: there is none)."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_ino, st.st_size, st.st_mtime_ns


def _lock_free(service_dir: Path) -> bool:
    """Whether no process (a service, ``fabric-cli doctor``) holds the lock of ``service_dir`` now."""
    try:
        with open(service_dir / "lock", "a+b") as fh:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            fcntl.flock(fh, fcntl.LOCK_UN)
        return True
    except BlockingIOError:
        return False
    except OSError:
        return True


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
    held: str | None = None        # not restarted (a restart cannot fix why it stopped): why
    held_file: Path | None = None  # ... the file it named: once that changes, it is started again
    held_since: tuple[int, int, int] | None = None


class CellProcesses:
    """The five service processes of one cell (plus the hub), started, supervised and stopped together.

    (Not the cell *model*, ``fabric.robot.cell.Cell``: this is the set of running processes.)"""

    def __init__(self, settings: SessionSettings, services: tuple[str, ...] = SERVICES, host_hub: bool = True,
                 log_dir: Path | None = None, extra_args: dict[str, list[str]] | None = None,
                 data_dir: Path | None = None, secure: Credentials | None = None) -> None:
        self.services, self.host_hub = services, host_hub
        self.log_dir, self.extra_args, self.data_dir = log_dir, extra_args or {}, data_dir
        self.secure = secure
        self.cell = settings.cell
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
        self.died = False              # a child exited while supervised
        self.killed: list[str] = []    # children that had to be killed (SIGKILL) by the last stop
        self._pgid: int | None = None
        self._notes: Path | None = None

    @property
    def procs(self) -> dict[str, subprocess.Popen]:
        """The current process of each service."""
        return {name: c.proc for name, c in self.children.items()}

    @property
    def held(self) -> dict[str, str]:
        """The services left stopped because a restart cannot fix why they stopped: why."""
        return {name: c.held for name, c in self.children.items() if c.held is not None}

    def start(self, deadline_s: float = 60.0, say=None, cancel: threading.Event | None = None) -> None:
        """Host the hub, start every service and wait until all are alive (or stop them all)."""
        self.launch()
        self.wait_up(deadline_s, say, cancel)

    def launch(self) -> None:
        """Host the hub, check that the cell is not served already, and start every service, without
        waiting (several cells start side by side). Call it from a thread that outlives the services:
        the kernel signals them when the thread that started them ends (``PR_SET_PDEATHSIG`` follows
        the thread, not the process). Raises ConfigError when the hub cannot be hosted (its port is
        taken), StateError when the cell is already served, ServiceUnavailable when the hub (``--no-hub``)
        cannot be reached."""
        if self.host_hub:
            self.hub = self._open_hub()
        try:
            self._check_cell_free()
        except BaseException:
            self._close_hub()
            raise
        self._notes = Path(tempfile.mkdtemp(prefix="am-fabric-up-"))
        for name in self.services:
            self.children[name] = _Child(name, self._spawn(name), time.monotonic())

    def _open_hub(self) -> zenoh.Session:
        try:
            return zenoh.open(self._hub_config())
        except zenoh.ZError as exc:
            where = ", ".join(self.hub_listen)
            reason = str(exc).split(" at /")[0]
            if "in use" in reason.lower():
                raise ConfigError(f"cannot host the hub on {where}: the address is in use (another 'fabric-cli up' "
                                  f"or 'fabric-cli router'?): stop it, host this hub elsewhere (--listen "
                                  f"tcp/127.0.0.1:PORT), or join that one (--no-hub --connect {where})",
                                  field="--listen", value=self.hub_listen) from None
            raise ConfigError(f"cannot host the hub on {where}: {reason}", field="--listen",
                              value=self.hub_listen) from None

    def _check_cell_free(self) -> None:
        """Refuse to start services of a cell that some of them already serve on this hub."""
        with Client.connect(self.client_settings) as client:
            alive = sorted(n for n, up in client.alive(timeout=1.0).items() if up and n in self.services)
        if alive:
            where = ", ".join(self.settings.connect)
            raise StateError(f"cell '{self.cell}' is already served on the hub at {where} ({', '.join(alive)} "
                             f"alive): stop that 'fabric-cli up' first, or start this one with another --cell",
                             state="running", command="up", services=alive)

    def wait_up(self, deadline_s: float = 60.0, say=None, cancel: threading.Event | None = None) -> None:
        """Wait until every service is alive, supervising them meanwhile (``say``: where to report); a
        service left stopped because a restart cannot fix it is not waited for (see :attr:`held`). If
        one is not alive by ``deadline_s``, stop them all and raise. Returns early when ``cancel`` is set."""
        end = time.monotonic() + deadline_s
        try:
            with Client.connect(self.client_settings) as client:
                changes = client.subscribe_alive()
                try:
                    while cancel is None or not cancel.is_set():
                        self.supervise(say or (lambda _: None))
                        wanted = {n for n in self.services if self.children[n].held is None}
                        alive = {n for n, up in client.alive(timeout=2.0).items() if up}
                        if wanted <= alive:
                            return
                        left = end - time.monotonic()
                        if left <= 0:
                            missing = sorted(wanted - alive)
                            raise ServiceUnavailable(f"not alive after {deadline_s:g} s: {', '.join(missing)}",
                                                     missing=missing)
                        with contextlib.suppress(queue.Empty):
                            changes.get(timeout=min(left, 0.25))
                finally:
                    changes.close()
        except (ServiceUnavailable, OSError) as exc:
            dead = {n: c.proc.poll() for n, c in self.children.items() if c.proc.poll() is not None}
            self.stop()
            raise ServiceUnavailable(f"services did not come up within {deadline_s:g} s ({exc}); exited: {dead}",
                                     exited=dead) from None

    def _hub_config(self) -> zenoh.Config:
        if self.secure is None:
            return zenoh_config(hub_settings(self.settings))
        return hub_zenoh_config(self.secure, self.settings, self.hub_listen)

    def _note(self, name: str) -> Path | None:
        return None if self._notes is None else self._notes / f"{name}.json"

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
        env[LAUNCHER_PID_ENV] = str(os.getpid())           # the child dies with this process (host.serve)
        note = self._note(name)
        if note is not None:
            note.unlink(missing_ok=True)
            env[EXIT_NOTE_ENV] = str(note)                 # where it says why a restart cannot help
        # the child writes to its own copy of the log file; the launcher's is closed once it is started
        with open(log, "ab") if log is not None else contextlib.nullcontext() as out:
            try:
                proc = self._popen(cmd, out, env, self._pgid or 0)
            except (PermissionError, subprocess.SubprocessError):
                # the group is gone (all its members exited): start a new one
                proc = self._popen(cmd, out, env, 0)
                self._pgid = proc.pid
        if self._pgid is None:
            self._pgid = proc.pid
        return proc

    @staticmethod
    def _popen(cmd: list[str], out, env: dict[str, str], pgid: int) -> subprocess.Popen:
        """Start ``cmd`` in process group ``pgid`` (0: a new group it leads). No Python code runs in the
        forked child before exec when Popen can set the group itself (3.11+)."""
        stderr = subprocess.STDOUT if out else None
        if sys.version_info >= (3, 11):
            return subprocess.Popen(cmd, stdout=out, stderr=stderr, env=env, process_group=pgid)
        return subprocess.Popen(cmd, stdout=out, stderr=stderr, env=env,
                                preexec_fn=lambda: os.setpgid(0, pgid))

    def respawn(self, name: str) -> subprocess.Popen:
        """Start service ``name`` again now (its previous process has exited)."""
        c = self.children[name]
        c.proc, c.started_s, c.due_s = self._spawn(name), time.monotonic(), None
        c.held = c.held_file = c.held_since = None
        return c.proc

    def supervise(self, say=print) -> bool:
        """Report children that exited, and restart them when their pause is over (a child that exited
        with EXIT_NO_RESTART: once the file it named has changed); True if any died."""
        died = False
        now = time.monotonic()
        for c in self.children.values():
            code = c.proc.poll()
            if c.held is not None:
                if self._repaired(c):
                    c.restarts += 1
                    say(f"   service {c.name}: {c.held_file} has changed (repaired or moved aside): started it "
                        f"again (pid {self.respawn(c.name).pid})")
                continue
            if code is not None and c.due_s is None:
                died = True
                c.codes.append(code)
                if code == EXIT_NO_RESTART:
                    say(self._hold(c))
                    continue
                if now - c.started_s >= HEALTHY_AFTER_S:
                    c.backoff_s = BACKOFF_FIRST_S
                c.due_s = now + c.backoff_s
                say(f"!! service {c.name} exited with code {code}; restarting it in {c.backoff_s:g} s"
                    + (f" (see {self.log_dir / (c.name + '.log')})" if self.log_dir else ""))
            elif c.due_s is not None and now >= c.due_s:
                c.proc, c.started_s, c.due_s = self._spawn(c.name), now, None
                c.restarts += 1
                c.backoff_s = min(c.backoff_s * 2.0, BACKOFF_MAX_S)
                say(f"   service {c.name} restarted (pid {c.proc.pid}, restart {c.restarts})")
        self.died = self.died or died
        return died

    def _hold(self, c: _Child) -> str:
        """Leave ``c`` stopped; the one line that says why, and what to do."""
        note: dict = {}
        path = self._note(c.name)
        if path is not None:
            with contextlib.suppress(OSError, ValueError):
                note = json.loads(path.read_text(encoding="utf-8"))
        log = f" (see {self.log_dir / (c.name + '.log')})" if self.log_dir else ""
        file = note.get("file") or ""
        if note.get("reason") == "damaged":
            c.held = f"{file or 'a database'} is damaged"
            c.held_file = Path(file) if file else None
            c.held_since = _signature(c.held_file) if c.held_file else None
            return (f"!! service {c.name} stopped: {c.held}; a restart cannot fix this, so it is not restarted "
                    f"(the rest of the cell keeps running): run '{note.get('doctor', 'fabric-cli doctor')}'; "
                    f"it starts again once the file is repaired")
        c.held = str(note.get("message") or f"exited with code {EXIT_NO_RESTART} (a restart cannot fix this)")
        return f"!! service {c.name} stopped and is not restarted (the rest of the cell keeps running): {c.held}{log}"

    def _repaired(self, c: _Child) -> bool:
        """Whether the file a held child named has been replaced, and no one (doctor) is still at work."""
        if c.held_file is None or _signature(c.held_file) == c.held_since:
            return False
        return _lock_free(service_data_dir(self.data_dir, self.cell, c.name))

    def stop(self, grace_s: float = STOP_GRACE_S) -> None:
        """SIGTERM to every child (the group), then SIGKILL to those still running after ``grace_s``."""
        # one SIGTERM each (a second one tells a service to end at once, without closing): the group's
        # (which reaches what the services started, too), and each child's that is not in it
        if self._pgid is not None:
            try:
                os.killpg(self._pgid, signal.SIGTERM)
            except (ProcessLookupError, PermissionError):
                pass                    # every member has already exited
        for c in self.children.values():
            if c.proc.poll() is None:
                try:
                    in_group = os.getpgid(c.proc.pid) == self._pgid
                except ProcessLookupError:
                    continue
                if not in_group:
                    c.proc.send_signal(signal.SIGTERM)
        end = time.monotonic() + grace_s
        self.killed = []
        for c in self.children.values():
            try:
                c.proc.wait(timeout=max(0.1, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                c.proc.kill()
                c.proc.wait()
                self.killed.append(c.name)
        self._close_hub()
        if self._notes is not None:
            shutil.rmtree(self._notes, ignore_errors=True)
            self._notes = None

    def _close_hub(self) -> None:
        """Close the hub's session, waiting no longer than HUB_CLOSE_S (a peer that does not answer can
        hold Zenoh's close for seconds; the process is about to end anyway)."""
        hub, self.hub = self.hub, None
        if hub is not None:
            t = threading.Thread(target=hub.close, name="hub-close", daemon=True)
            t.start()
            t.join(HUB_CLOSE_S)


def stop_print_first(settings: SessionSettings, say=print, wait_s: float = STOP_PRINT_WAIT_S,
                     hurry: threading.Event | None = None) -> None:
    """Before the cell goes down: a print in progress is stopped cleanly (``stopped`` recorded). Gives up
    waiting for it when ``hurry`` is set (a second Ctrl-C)."""
    try:
        with Client.connect(settings) as client:
            state = client.state().state
            if not state.in_print:
                return
            events = client.subscribe("station", "events")
            try:
                client.stop()
                end = time.monotonic() + wait_s
                while time.monotonic() < end and not (hurry is not None and hurry.is_set()):
                    try:
                        ev = events.get(timeout=min(0.25, max(0.01, end - time.monotonic())))
                    except queue.Empty:
                        continue
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
    """Start the cell, report where it is, supervise until Ctrl-C, stop a running print, then stop everything.
    A second Ctrl-C (or SIGTERM) stops the services without waiting for the print to stop."""
    cell = CellProcesses(settings, services, host_hub, log_dir, extra_args, data_dir, secure)
    stop, hurry = threading.Event(), threading.Event()

    on_signals(lambda: hurry if stop.is_set() else stop)      # the first signal stops, the second hurries
    t0 = time.monotonic()
    try:
        cell.launch()
    except FabricError as err:                  # port in use, cell already served, hub unreachable: one line
        out(f"!! {err.message}")
        return 1
    try:
        cell.wait_up(say=out, cancel=stop)
    except ServiceUnavailable as err:           # (it has stopped them)
        out(f"!! {err.message}")
        return 1
    except BaseException:
        cell.stop()
        raise
    try:
        if not stop.is_set():
            _say_up(cell, settings, host_hub, secure, time.monotonic() - t0, out)
        while not stop.wait(0.2):
            cell.supervise(out)
    finally:
        if "station" in services and not hurry.is_set() and "station" not in cell.held:
            stop_print_first(cell.client_settings, out, hurry=hurry)
        out("stopping services ...")
        cell.stop()
        out(_stopped_line(cell, host_hub))
    return 1 if cell.died else 0


def _stopped_line(cell: CellProcesses, host_hub: bool) -> str:
    """The launcher's last line: how the cell ended."""
    ran = [n for n in cell.children if n not in cell.held]
    ended = [n for n in ran if n not in cell.killed]
    line = f"cell '{cell.cell}' stopped: {len(ended)} service{'s' if len(ended) != 1 else ''} ended"
    if cell.killed:
        line += f", {', '.join(cell.killed)} killed (no exit within {STOP_GRACE_S:g} s)"
    if cell.held:
        line += f"; {', '.join(cell.held)} had stopped before (see above)"
    return line + ("; hub closed" if host_hub and cell.children else "")


def _say_up(cell: CellProcesses, settings: SessionSettings, host_hub: bool, secure: Credentials | None,
            took_s: float, out) -> None:
    hub = ", ".join(cell.settings.connect)
    held = cell.held
    out(f"cell '{settings.cell}' up in {took_s:.1f} s; hub {hub if host_hub else '(external) ' + hub}"
        + (f" (TLS, passwords, roles: {secure.root})" if secure is not None else "")
        + (f"; not running: {', '.join(held)} (see above)" if held else ""))
    keys = Keys(settings.cell)
    for name, p in cell.procs.items():
        if name in held:
            out(f"  {name:<11} stopped     {held[name]}")
        else:
            out(f"  {name:<11} pid {p.pid:<7} {keys.cmd_all(name)}")
    out("Ctrl-C stops the print (if one runs), then every service.")
