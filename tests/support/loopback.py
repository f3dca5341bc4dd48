"""Real fabric endpoints on loopback, for the slow tier: a free port, fresh session settings, a relay process."""
from __future__ import annotations

import contextlib
import socket
import subprocess
import sys
import uuid
from collections.abc import Iterator

from fabric.wire.config import SessionSettings

__all__ = ["free_port", "make_settings", "relay_process"]


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def make_settings() -> SessionSettings:
    """Settings of a fresh hub endpoint on loopback and a fresh cell name."""
    return SessionSettings(connect=[f"tcp/127.0.0.1:{free_port()}"], cell=f"t{uuid.uuid4().hex[:8]}")


@contextlib.contextmanager
def relay_process(*args: str) -> Iterator[subprocess.Popen[str]]:
    """``fabric-cli relay ARGS`` as a process of its own, up when entered, stopped on exit."""
    proc = subprocess.Popen([sys.executable, "-m", "fabric.cli.main", "relay", *args], stdout=subprocess.PIPE,
                            text=True)
    try:
        assert proc.stdout is not None and "fabric relay listening on" in proc.stdout.readline()
        yield proc
    finally:
        proc.terminate()
        proc.wait(timeout=30)
