"""franky-sim as a process for the robot tests: a Franka FR3 in MuJoCo behind the libfranka network protocol.

Each simulator binds its own loopback address (127.0.0.N: libfranka's port is fixed at 1337), so xdist's
workers and a test's second simulator never meet. Skips the test with the reason when franky-control or
franky-sim is not installed (the test extra brings both).
"""
from __future__ import annotations

import importlib.util
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

__all__ = ["FrankySim", "need_franky", "free_loopback", "favour", "at_rest_s"]

READY_TEXT = "Connect to the server using"
START_TIMEOUT_S = 60.0


def favour(pid: int, niceness: int = -10) -> None:
    """Give a process that must keep a 1 kHz loop (the simulator, the station that drives it) the CPU first,
    where this user may (as a real robot's host runs its control at real-time priority); else leave it be.
    Every thread of it (Linux's niceness is a thread's; threads made later inherit their maker's)."""
    tasks = Path(f"/proc/{pid}/task")
    for tid in ([int(d.name) for d in tasks.iterdir()] if tasks.is_dir() else [pid]):
        try:
            os.setpriority(os.PRIO_PROCESS, tid, niceness)
        except (PermissionError, OSError):
            pass


def at_rest_s(position_deg: Callable[[], list[float]], timeout_s: float) -> float:
    """When the arm came to rest (monotonic s): its joints, as ``position_deg()`` reads them (a station's
    ``position``), within 0.01 deg over 0.2 s. AssertionError if it does not within ``timeout_s``."""
    t0 = time.monotonic()
    seen: list[tuple[float, np.ndarray]] = []
    while time.monotonic() - t0 < timeout_s:
        now = time.monotonic()
        seen.append((now, np.array(position_deg())))
        old = [q for t, q in seen if now - t >= 0.2]
        if old and np.abs(seen[-1][1] - old[-1]).max() < 0.01:
            return next(t for t, q in seen if np.abs(q - seen[-1][1]).max() < 0.01)
        time.sleep(0.01)                         # polling the pose, bounded by the deadline
    raise AssertionError(f"the arm did not come to rest within {timeout_s} s")


def need_franky() -> None:
    """Skip unless franky-control and franky-sim are installed."""
    for module, dist in (("franky", "franky-control"), ("franky_sim", "franky-sim")):
        if importlib.util.find_spec(module) is None:
            pytest.skip(f"{dist} is not installed (the test extra brings it): the robot tests need it")


def free_loopback() -> str:
    """A loopback address whose port 1337 is free (127.0.N.M by worker and process)."""
    import socket
    base = (os.getpid() % 200) + 20
    for k in range(1, 250):
        host = f"127.0.{base}.{k}"
        with socket.socket() as s:
            try:
                s.bind((host, 1337))
            except OSError:
                continue
            return host
    raise RuntimeError("no free loopback address for franky-sim")


_OTHER_VERSION = """
import struct
import sys
import franky_sim.franka_server as fs
from franky_sim import run_server

def refuse(self, server, command_type_struct="I"):
    # what a robot with another system image answers: incompatible, and its own version (libfranka's reply
    # is a packed uint8 status and uint16 version)
    header = fs.MessageHeader(self.command_type, self.command_id, 8).to_bytes(command_type_struct=command_type_struct)
    self.client_socket.sendall(header + struct.pack("<BH5x", fs.ConnectStatus.kIncompatibleLibraryVersion.value,
                                                    {version}))

fs.ConnectCommand.handle = refuse
sys.argv = ["franky-sim"] + sys.argv[1:]
run_server.main()
"""
"""franky-sim whose robot server runs another version: it refuses libfranka's connect, naming its own."""


class FrankySim:
    """``franky-sim --hostname HOST`` as a child process; its output goes to ``log``."""

    def __init__(self, log: Path, host: str | None = None, server_version: int | None = None) -> None:
        self.host = host or free_loopback()
        self.log = log
        self.server_version = server_version     # None: franky-sim's own; else a server that says this one
        self.proc: subprocess.Popen | None = None

    def start(self) -> FrankySim:
        exe = Path(sys.executable).with_name("franky-sim")
        cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "franky_sim.run_server"]
        if self.server_version is not None:
            cmd = [sys.executable, "-c", _OTHER_VERSION.format(version=int(self.server_version))]
        self._out = open(self.log, "ab")  # noqa: SIM115 - held for the process's life
        seen = self.log.stat().st_size            # a log appended to: only this run's lines count
        self.proc = subprocess.Popen(cmd + ["-s", "mujoco", "--hostname", self.host], stdout=self._out,
                                     stderr=subprocess.STDOUT, start_new_session=True,
                                     env={**os.environ, "PYTHONUNBUFFERED": "1", "MUJOCO_GL": "disable"})
        favour(self.proc.pid)
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if READY_TEXT in self.log.read_bytes()[seen:].decode(errors="replace"):
                return self
            if self.proc.poll() is not None:
                raise RuntimeError(f"franky-sim exited with {self.proc.returncode}: {self.log.read_text()[-2000:]}")
            time.sleep(0.1)                      # polling its log, bounded by the deadline
        self.kill()
        raise RuntimeError(f"franky-sim did not start within {START_TIMEOUT_S:g} s: {self.log.read_text()[-2000:]}")

    def kill(self, sig: int = signal.SIGKILL) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, sig)
            self.proc.wait(10)
        if getattr(self, "_out", None) is not None:
            self._out.close()
            self._out = None

    def __enter__(self) -> FrankySim:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.kill()
