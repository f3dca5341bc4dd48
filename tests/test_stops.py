"""Clean stops: every service ends within 5 s of SIGTERM/SIGINT whatever the fabric's state, nothing outlives
``fabric-cli up`` however it ends, a dead lock holder never blocks, and a second ``up`` for a served cell or on
a taken port is one line. Real processes; every wait is on a condition with a deadline."""
from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import replace
from pathlib import Path

import pytest

from fabric.cli import up as launcher
from fabric.client import Client
from fabric.server.service import lock_dir
from fabric.signals import on_signals
from fabric.wire.config import SessionSettings
from fabric.wire.errors import StateError
from fabric.wire.keys import SERVICES

from support.loopback import free_port
from support.proc_lines import ProcLines, wait_until

pytestmark = pytest.mark.timeout(240)
CLI = [sys.executable, "-m", "fabric.cli.main"]


def _running(pid: int) -> bool:
    """Whether any thread of ``pid`` still runs: a zombie leader whose other threads are still ending (one
    in an fsync, say) holds its files, and so its locks, until the last is gone."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            zombie = fh.read().rsplit(")", 1)[1].split()[0] == "Z"
        return not zombie or len(os.listdir(f"/proc/{pid}/task")) > 1
    except FileNotFoundError:
        return False


def _router(endpoint: str) -> subprocess.Popen:
    proc = subprocess.Popen([*CLI, "router", "--listen", endpoint], stdout=subprocess.PIPE, text=True)
    assert "fabric hub listening" in proc.stdout.readline()
    return proc


def _up(*args: str) -> tuple[subprocess.Popen, ProcLines]:
    proc = subprocess.Popen([*CLI, "up", *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    return proc, ProcLines(proc)


def _pids(lines: ProcLines) -> dict[str, int]:
    return {m.group(1): int(m.group(2)) for m in (re.match(r"\s+(\w+)\s+pid (\d+)", ln) for ln in lines.lines) if m}


def _reap(*procs: subprocess.Popen) -> None:
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


# --- every service, the hub gone ------------------------------------------------------------------

@pytest.mark.parametrize("hub_fate,sig", [("killed", signal.SIGINT), ("frozen", signal.SIGTERM)])
def test_every_service_exits_within_5_s_of_a_signal_with_the_hub_gone(tmp_path, hub_fate, sig):
    """Killed: the hub's process is gone (kill -9). Frozen: it is there but never answers, as when its host
    is cut off (SIGSTOP): Zenoh's close then waits some ten seconds for it. Each service has a hub of its
    own (and a cell of its own), so that the hub is its only link, as for a service whose hub is on
    another host."""
    hubs, procs = {}, {}
    for name in SERVICES:
        endpoint, cell = f"tcp/127.0.0.1:{free_port()}", f"s{uuid.uuid4().hex[:8]}"
        hubs[name] = (_router(endpoint), endpoint, cell)
        with open(tmp_path / f"{name}.log", "ab") as log:        # the child keeps its own copy
            procs[name] = subprocess.Popen([*CLI, "serve", name, "--connect", endpoint, "--cell", cell,
                                            "--data-dir", str(tmp_path / "data")], stdout=log, stderr=subprocess.STDOUT)
    try:
        for name, (_, endpoint, cell) in hubs.items():
            with Client.connect(SessionSettings(connect=[endpoint], cell=cell, mode="client")) as client:
                client.wait_alive((name,), deadline_s=90)
        for hub, _, _ in hubs.values():
            if hub_fate == "killed":
                hub.kill()
                hub.wait()
            else:
                hub.send_signal(signal.SIGSTOP)
        # the scenario: the hub has been gone for two seconds (two leases) when the signal comes. Not a wait
        # for something to happen; a frozen hub's link is given up by then, and Zenoh's close still waits on it
        time.sleep(2.0)
        t0 = time.monotonic()
        for proc in procs.values():
            proc.send_signal(sig)
        took = {}
        for name, proc in procs.items():
            try:
                code = proc.wait(timeout=max(0.1, t0 + 5.0 - time.monotonic()))
            except subprocess.TimeoutExpired:
                code = None
            took[name] = (code, round(time.monotonic() - t0, 2))
        logs = {n: (tmp_path / f"{n}.log").read_text() for n in SERVICES}
        assert all(code == 0 for code, _ in took.values()), (took, logs)
        assert all("Traceback" not in log for log in logs.values()), logs
    finally:
        for hub, _, _ in hubs.values():
            if hub.poll() is None:
                hub.send_signal(signal.SIGCONT)
        _reap(*(h for h, _, _ in hubs.values()), *procs.values())


# --- a burst of signals ---------------------------------------------------------------------------

def _burst(proc: subprocess.Popen, n: int = 300) -> None:
    """Signals back to back, as when Ctrl-C is pressed twice and the terminal hangs up on top."""
    for k in range(n):
        try:
            os.kill(proc.pid, signal.SIGTERM if k % 2 else signal.SIGINT)
        except ProcessLookupError:
            return


def test_a_signal_sets_the_event_even_where_the_event_holds_its_own_lock():
    """Where a signal can land: inside the main thread's own ``Event.set()`` or ``Event.wait()``, which hold the
    event's (non-reentrant) lock, or inside ``Thread.start()``, which holds threading's own lock. A handler
    calling ``set()`` (or starting a thread) there waited for that lock forever; now no handler takes a lock."""
    stop = threading.Event()
    events = on_signals(lambda: stop, (signal.SIGUSR1,))
    try:
        with stop._cond:                              # (the event's lock, held as set() and wait() hold it)
            os.kill(os.getpid(), signal.SIGUSR1)      # the handler runs here, in this thread, and returns
        assert stop.wait(5.0)                         # and the event is set once the lock is free
        stop.clear()
        with threading._active_limbo_lock:            # (Thread.start()'s lock)
            os.kill(os.getpid(), signal.SIGUSR1)
        assert stop.wait(5.0)
    finally:
        events.close()


def test_a_burst_of_signals_never_freezes_a_service_or_the_hub(tmp_path):
    """A handler that set the stop event itself ran between the bytecodes of the event's own lock and waited
    for it forever: a service was found alive an hour after its launcher was stopped. Services and the hub
    end within the 5 s deadline however many signals arrive at once."""
    endpoint, cell = f"tcp/127.0.0.1:{free_port()}", f"s{uuid.uuid4().hex[:8]}"
    hub = _router(endpoint)
    procs = {}
    try:
        for name in ("slicer", "supervisor"):
            with open(tmp_path / f"{name}.log", "ab") as log:
                procs[name] = subprocess.Popen([*CLI, "serve", name, "--connect", endpoint, "--cell", cell,
                                                "--data-dir", str(tmp_path / "data")], stdout=log,
                                               stderr=subprocess.STDOUT)
        settings = SessionSettings(connect=[endpoint], cell=cell, mode="client")
        with Client.connect(settings) as client:
            client.wait_alive(tuple(procs), deadline_s=60)
        for _round in range(3):                      # three bursts on each: each must end it
            for proc in procs.values():
                _burst(proc, 100)
        for name, proc in procs.items():
            try:
                proc.wait(timeout=8.0)
            except subprocess.TimeoutExpired:
                raise AssertionError(f"{name} still running 8 s after a burst of signals") from None
        _burst(hub)
        try:
            hub.wait(timeout=8.0)
        except subprocess.TimeoutExpired:
            raise AssertionError("the hub still running 8 s after a burst of signals") from None
    finally:
        _reap(hub, *procs.values())


# --- nothing outlives up ---------------------------------------------------------------------------

@pytest.mark.parametrize("how", ["SIGKILL", "SIGINT then SIGKILL"])
def test_no_service_outlives_up_however_it_ends_and_their_locks_are_free(tmp_path, how):
    cell, data = f"s{uuid.uuid4().hex[:8]}", tmp_path / "data"
    proc, out = _up("--cell", cell, "--listen", f"tcp/127.0.0.1:{free_port()}", "--data-dir", str(data),
                    "--log-dir", str(tmp_path / "logs"))
    try:
        assert out.wait(r"Ctrl-C stops", 90) is not None, out.text
        pids = _pids(out)
        assert set(pids) == set(SERVICES) and all(_running(p) for p in pids.values())
        if how != "SIGKILL":
            proc.send_signal(signal.SIGINT)
            assert out.wait(r"stopping services", 30) is not None, out.text
        proc.kill()                                  # the launcher, and the hub in it, are gone at once
        proc.wait()
        wait_until(lambda: not any(_running(p) for p in pids.values()), 6.0,
                    f"every service ending after {how} of up ({ {n: _running(p) for n, p in pids.items()} })")
        for name in SERVICES:                         # and nothing holds their locks: the next up can start them
            lock_dir(data / cell / name, name, cell).close()
    finally:
        _reap(proc)


def test_a_lock_whose_holder_died_never_blocks_and_a_live_one_is_named(tmp_path):
    folder = tmp_path / "c1" / "planner"
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time; from pathlib import Path; from fabric.server.service import lock_dir\n"
        f"fh = lock_dir(Path({str(folder)!r}), 'planner', 'c1'); print('locked', flush=True); time.sleep(600)")],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(StateError) as err:
            lock_dir(folder, "planner", "c1")
        assert f"pid {holder.pid}" in err.value.message and "already running on this host" in err.value.message
        assert (folder / "lock").read_text().startswith(f"{holder.pid} ")     # the refusal did not erase it
        holder.kill()
        holder.wait()
        lock_dir(folder, "planner", "c1").close()   # at once: the kernel released it with its holder
    finally:
        _reap(holder)


# --- a second up -----------------------------------------------------------------------------------

def test_a_second_up_for_a_cell_served_on_the_hub_is_refused_in_one_line(tmp_path):
    cell, endpoint = f"s{uuid.uuid4().hex[:8]}", f"tcp/127.0.0.1:{free_port()}"
    first, out = _up("--cell", cell, "--listen", endpoint, "--data-dir", str(tmp_path / "a"),
                     "--log-dir", str(tmp_path / "logs-a"))
    second = None
    try:
        assert out.wait(r"Ctrl-C stops", 90) is not None, out.text
        pids = _pids(out)
        second = subprocess.run([*CLI, "up", "--cell", cell, "--no-hub", "--connect", endpoint,
                                 "--data-dir", str(tmp_path / "b"), "--log-dir", str(tmp_path / "logs-b")],
                                capture_output=True, text=True, timeout=60)
        said = [ln for ln in (second.stdout + second.stderr).splitlines() if ln.strip()]
        assert second.returncode != 0, said
        assert len(said) == 1, said
        assert said[0].startswith(f"!! cell '{cell}' is already served on the hub at {endpoint}"), said
        assert not (tmp_path / "logs-b").exists()     # nothing was started
        assert all(_running(p) for p in pids.values())   # the cell served keeps serving, untouched
        assert out.wait(r"exited|restarted", 1.0) is None, out.text
    finally:
        first.send_signal(signal.SIGINT)
        assert first.wait(timeout=60) == 0, out.text
        _reap(first)


def test_up_on_a_port_in_use_says_so_in_one_line():
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        endpoint = f"tcp/127.0.0.1:{taken.getsockname()[1]}"
        done = subprocess.run([*CLI, "up", "--cell", f"s{uuid.uuid4().hex[:8]}", "--listen", endpoint],
                              capture_output=True, text=True, timeout=60)
    said = [ln for ln in (done.stdout + done.stderr).splitlines() if ln.strip()]
    assert done.returncode != 0 and len(said) == 1, said
    assert said[0].startswith(f"!! cannot host the hub on {endpoint}: the address is in use"), said


# --- the restart back-off ------------------------------------------------------------------------------

class _FakeProc:
    def __init__(self, pid: int) -> None:
        self.pid, self.code = pid, None

    def poll(self):
        return self.code


def test_the_restart_backoff_grows_and_starts_over_after_a_healthy_run(monkeypatch, tmp_path):
    clock = {"t": 1000.0}
    monkeypatch.setattr(launcher.time, "monotonic", lambda: clock["t"])
    spawned = []

    def spawn(self, name):
        spawned.append(_FakeProc(len(spawned) + 1))
        return spawned[-1]

    monkeypatch.setattr(launcher.CellProcesses, "_spawn", spawn)
    cell = launcher.CellProcesses(replace(SessionSettings(cell="c1"), connect=["tcp/127.0.0.1:1"]),
                                  services=("planner",), log_dir=None, data_dir=Path(tmp_path))
    cell.children["planner"] = launcher._Child("planner", spawn(cell, "planner"), clock["t"])
    said: list[str] = []

    def crash_after(run_s: float) -> float:
        """The current process runs ``run_s`` and dies; the pause before it is started again."""
        clock["t"] += run_s
        cell.children["planner"].proc.code = 1
        assert cell.supervise(said.append)
        pause = cell.children["planner"].due_s - clock["t"]
        clock["t"] += pause
        cell.supervise(said.append)                  # restarted now
        assert cell.children["planner"].proc.code is None
        return pause

    assert [crash_after(1.0) for _ in range(8)] == [0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 30.0, 30.0]
    assert crash_after(launcher.HEALTHY_AFTER_S + 1.0) == 0.5       # a healthy minute: from the start again
    assert crash_after(1.0) == 1.0
    assert len(spawned) == 11 and all("restarted" in ln or "exited" in ln for ln in said)
