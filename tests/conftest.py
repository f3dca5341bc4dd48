"""Shared fixtures: Zenoh sessions on free loopback ports (scouting off) and the whole cell as processes."""
from __future__ import annotations

import contextlib
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import uuid
from pathlib import Path

import pytest
import zenoh

from fabric.cli.up import CellProcesses, hub_settings
from fabric.client import wait_connected
from fabric.wire.config import DATA_ROOT_ENV, SessionSettings, zenoh_config


def pytest_configure(config) -> None:
    """Services started by tests keep their durable state in a folder of this run, never in the user's
    data folder (subprocesses inherit the variable)."""
    root = tempfile.mkdtemp(prefix="am-fabric-tests-")
    os.environ[DATA_ROOT_ENV] = root
    config._fabric_data_root = root


def pytest_unconfigure(config) -> None:
    shutil.rmtree(getattr(config, "_fabric_data_root", ""), ignore_errors=True)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def relay_process(*args: str):
    """``fabric-cli relay ARGS`` as a process of its own, up when entered, stopped on exit."""
    proc = subprocess.Popen([sys.executable, "-m", "fabric.cli.main", "relay", *args], stdout=subprocess.PIPE,
                            text=True)
    try:
        assert "fabric relay listening on" in proc.stdout.readline()
        yield proc
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def make_settings() -> SessionSettings:
    return SessionSettings(connect=[f"tcp/127.0.0.1:{free_port()}"], cell=f"t{uuid.uuid4().hex[:8]}")


@pytest.fixture
def settings() -> SessionSettings:
    """Fresh hub endpoint and cell name per test."""
    return make_settings()


@pytest.fixture
def hub(settings):
    """An in-process router session hosting the hub endpoint."""
    with zenoh.open(zenoh_config(hub_settings(settings))) as session:
        yield session


@pytest.fixture
def session(hub, settings):
    """A peer session connected to the hub."""
    with zenoh.open(zenoh_config(settings)) as s:
        yield s


@pytest.fixture
def peers():
    """Two in-process peers: one listens on a free loopback port, the other connects to it."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    a = zenoh.open(zenoh_config(SessionSettings(listen=[ep], connect=[])))
    b = zenoh.open(zenoh_config(SessionSettings(connect=[ep])))
    assert wait_connected(b, 30.0), "the second peer never linked to the first"
    yield a, b
    b.close()
    a.close()


@pytest.fixture(scope="session")
def running_cell(tmp_path_factory):
    """The five services as separate processes, awaited by liveliness with a deadline."""
    st = make_settings()
    logs = Path(tmp_path_factory.mktemp("cell-logs"))
    cell = CellProcesses(st, log_dir=logs, data_dir=Path(tmp_path_factory.mktemp("cell-data")))
    cell.start(deadline_s=90.0)
    yield cell
    cell.stop()


@pytest.fixture(scope="module")
def cert(cell):
    """The collision certifier of the test module's ``cell`` fixture."""
    from fabric.collision.certify import Certifier
    return Certifier(cell)
