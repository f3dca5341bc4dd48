"""``fabric-cli up``: host the fabric hub and run every service as its own process on one host."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import zenoh

from fabric.client import Client
from fabric.config import SessionSettings, zenoh_config
from fabric.errors import ServiceUnavailable
from fabric.keys import SERVICES, Keys

__all__ = ["CellProcesses", "hub_settings", "run_up"]


def hub_settings(settings: SessionSettings) -> SessionSettings:
    """The router session that hosts the hub endpoint the services connect to."""
    return replace(settings, mode="router", listen=list(settings.listen or settings.connect), connect=[])


class CellProcesses:
    """The five service processes of one cell (plus the hub), started and stopped together.

    (Not the cell *model*, ``fabric.robot.cell.Cell``: this is the set of running processes.)"""

    def __init__(self, settings: SessionSettings, services: tuple[str, ...] = SERVICES, host_hub: bool = True,
                 log_dir: Path | None = None, extra_args: dict[str, list[str]] | None = None) -> None:
        self.settings, self.services, self.host_hub = settings, services, host_hub
        self.log_dir, self.extra_args = log_dir, extra_args or {}
        self.procs: dict[str, subprocess.Popen] = {}
        self.hub: zenoh.Session | None = None
        self.exited: dict[str, int] = {}

    def start(self, deadline_s: float = 60.0) -> None:
        if self.host_hub:
            self.hub = zenoh.open(zenoh_config(hub_settings(self.settings)))
        for name in self.services:
            self.spawn(name)
        with Client.connect(self.settings) as client:
            try:
                client.wait_alive(self.services, deadline_s)
            except ServiceUnavailable:
                dead = {n: p.poll() for n, p in self.procs.items() if p.poll() is not None}
                self.stop()
                raise ServiceUnavailable(f"services did not come up within {deadline_s:g} s; exited: {dead}",
                                         exited=dead) from None

    def spawn(self, name: str) -> subprocess.Popen:
        child = replace(self.settings, listen=[])      # children connect to the hub; they never take its port
        cmd = [sys.executable, "-m", "fabric.cli.main", "serve", name, *child.to_args(),
               *self.extra_args.get(name, [])]
        out = None
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            out = open(self.log_dir / f"{name}.log", "ab")
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT if out else None, env=env,
                                start_new_session=True)
        self.procs[name] = proc
        return proc

    def poll_dead(self) -> dict[str, int]:
        """Children that exited since the last call (name -> exit code)."""
        new = {}
        for name, p in self.procs.items():
            rc = p.poll()
            if rc is not None and name not in self.exited:
                self.exited[name] = new[name] = rc
        return new

    def stop(self, grace_s: float = 5.0) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        end = time.monotonic() + grace_s
        for p in self.procs.values():
            try:
                p.wait(timeout=max(0.1, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        if self.hub is not None:
            self.hub.close()
            self.hub = None


def run_up(settings: SessionSettings, services: tuple[str, ...], host_hub: bool, log_dir: Path | None,
           extra_args: dict[str, list[str]], out=print) -> int:
    """Start the cell, report where it is, supervise until Ctrl-C, then stop everything."""
    cell = CellProcesses(settings, services, host_hub, log_dir, extra_args)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    t0 = time.monotonic()
    cell.start()
    out(f"cell '{settings.cell}' up in {time.monotonic() - t0:.1f} s; hub "
        f"{', '.join(settings.connect) if host_hub else '(external) ' + ', '.join(settings.connect)}")
    keys = Keys(settings.cell)
    for name, p in cell.procs.items():
        out(f"  {name:<11} pid {p.pid:<7} {keys.cmd_all(name)}")
    out("Ctrl-C stops every service.")
    rc = 0
    try:
        while not stop.wait(0.2):
            for name, code in cell.poll_dead().items():
                out(f"!! service {name} exited with code {code}" + (f" (see {log_dir / (name + '.log')})" if log_dir else ""))
                rc = 1
    finally:
        out("stopping services ...")
        cell.stop()
    return rc
