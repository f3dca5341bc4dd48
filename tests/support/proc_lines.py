"""Helpers for tests that run processes: read a process's output lines as they come, and wait for a condition."""
from __future__ import annotations

import queue
import re
import subprocess
import threading
import time
from collections.abc import Callable


class ProcLines:
    """A process's output lines, read by a thread; wait for one matching a pattern, with a deadline."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.lines: list[str] = []
        self._q: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, args=(proc,), daemon=True).start()

    def _read(self, proc: subprocess.Popen) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            self.lines.append(line)
            self._q.put(line)

    def wait(self, pattern: str, timeout: float) -> str | None:
        """The first line from now on matching ``pattern``; None when none came within ``timeout``."""
        end = time.monotonic() + timeout
        while (left := end - time.monotonic()) > 0:
            try:
                line = self._q.get(timeout=left)
            except queue.Empty:
                return None
            if re.search(pattern, line):
                return line
        return None

    @property
    def text(self) -> str:
        return "".join(self.lines)


def wait_until(predicate: Callable[[], bool], timeout: float, what: str) -> None:
    """Poll ``predicate`` until it holds; fail naming ``what`` after ``timeout`` seconds."""
    end = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < end, f"{what}: not within {timeout:g} s"
        time.sleep(0.05)                          # polling the condition, not a synchronising sleep
