"""The tiers of the suite: which tests form the fast tier, and the guard that proves they belong to it.

A test is **fast** unless one of these says otherwise (``slow_reasons``):

- it uses a fixture of real sessions or processes (``hub``, ``session``, ``peers``, ``settings``,
  ``running_cell``, or any fixture built on them: pytest's fixture closure);
- it is marked ``slow`` (long) or ``slicers`` (runs the Debian slicers);
- its module opens sessions or starts processes itself, as its source shows (``module_reasons``): it imports
  ``subprocess`` or ``multiprocessing``, calls ``zenoh.open``, ``Client.connect`` or ``open_session``, starts
  ``CellProcesses``, or imports the slow tier's helpers (``support.loopback``, ``support.faults``,
  ``support.proc_lines``, ``test_multihost``).

The fast tier runs with :class:`FastTierGuard` installed: ``zenoh.open`` and starting a fabric process (a
Python interpreter, a ``fabric-*`` program) raise :class:`FastTierViolation`, and a test that tried either
fails even if the code under test caught the error: a test the rule put in the fast tier by mistake fails
loudly. Other programs (a C compiler building ``fabric.native``, a slicer asked its version) may run.
"""
from __future__ import annotations

import ast
import functools
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import zenoh

__all__ = ["SLOW_FIXTURES", "SLOW_MARKERS", "slow_reasons", "module_reasons", "FastTierGuard", "FastTierViolation"]

SLOW_FIXTURES = frozenset({"hub", "session", "peers", "settings", "running_cell"})
SLOW_MARKERS = frozenset({"slow", "slicers"})
PROCESS_MODULES = frozenset({"subprocess", "multiprocessing"})
SLOW_HELPERS = frozenset({"support.loopback", "support.faults", "support.proc_lines", "test_multihost"})
SESSION_CALLS = {("zenoh", "open"): "opens a Zenoh session (zenoh.open)",
                 ("Client", "connect"): "opens a Zenoh session (Client.connect)"}
SESSION_NAMES = {"open_session": "opens a Zenoh session (open_session)",
                 "CellProcesses": "starts the cell's processes (CellProcesses)"}


def slow_reasons(item: pytest.Item) -> list[str]:
    """Why ``item`` is not in the fast tier (empty: it is)."""
    reasons = [f"uses the {name} fixture" for name in sorted(SLOW_FIXTURES & set(getattr(item, "fixturenames", ())))]
    reasons += [f"marked {mark.name}" for mark in item.iter_markers() if mark.name in SLOW_MARKERS]
    return reasons + list(module_reasons(str(item.path)))


@functools.cache
def module_reasons(path: str) -> tuple[str, ...]:
    """What in a test module's source opens a session or starts a process (read once per module)."""
    tree = ast.parse(Path(path).read_text(encoding="utf-8"), filename=path)
    found: dict[str, None] = {}                   # ordered, without repeats
    for node in ast.walk(tree):
        for reason in _node_reasons(node):
            found.setdefault(reason)
    return tuple(found)


def _node_reasons(node: ast.AST) -> list[str]:
    if isinstance(node, ast.Import):
        return [_imported(alias.name) for alias in node.names if _imported(alias.name)]
    if isinstance(node, ast.ImportFrom) and node.module:
        names = [SESSION_NAMES[alias.name] for alias in node.names if alias.name in SESSION_NAMES]
        return ([_imported(node.module)] if _imported(node.module) else []) + names
    if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
        reason = SESSION_CALLS.get((node.value.id, node.attr))
        return [reason] if reason else []
    if isinstance(node, ast.Name) and node.id in SESSION_NAMES:
        return [SESSION_NAMES[node.id]]
    return []


def _imported(module: str) -> str:
    """The reason an import makes a module slow, or ''."""
    if module.split(".")[0] in PROCESS_MODULES:
        return f"starts processes (imports {module})"
    if module in SLOW_HELPERS:
        return f"uses the slow tier's helpers ({module})"
    return ""


class FastTierViolation(RuntimeError):
    """A fast-tier test opened a real Zenoh session or started a fabric process."""


class FastTierGuard:
    """Refuses ``zenoh.open`` and fabric processes while installed, and remembers each attempt."""

    def __init__(self) -> None:
        self.attempts: list[str] = []

    def install(self, patch: pytest.MonkeyPatch) -> None:
        """Patch ``zenoh.open`` and ``subprocess.Popen`` (undone by ``patch.undo()``)."""
        guard = self
        real_popen = subprocess.Popen

        def refuse_open(*_args: Any, **_kwargs: Any) -> Any:
            raise guard.violation("opened a Zenoh session (zenoh.open)")

        class GuardedPopen(real_popen):  # type: ignore[valid-type, misc]
            def __new__(cls, args: Any, *_rest: Any, **_kwargs: Any) -> Any:     # refused before any object exists
                if is_fabric_process(args):
                    raise guard.violation(f"started a fabric process: {args!r}")
                return super().__new__(cls)

        patch.setattr(zenoh, "open", refuse_open)
        patch.setattr(subprocess, "Popen", GuardedPopen)

    def violation(self, what: str) -> FastTierViolation:
        self.attempts.append(what)
        return FastTierViolation(f"a fast-tier test {what}: it belongs to the slow tier (use a real-session "
                                 f"fixture, or mark it slow), or should run over fabric.wire.memory")

    def take(self) -> list[str]:
        """The attempts since the last call."""
        taken, self.attempts = self.attempts, []
        return taken


def is_fabric_process(args: Any) -> bool:
    """Whether a command line starts Python (so: fabric code) or a ``fabric-*`` program."""
    argv = [args] if isinstance(args, (str, bytes, os.PathLike)) else list(args)
    if not argv:
        return False
    words = os.fsdecode(argv[0]).split()
    program = words[0] if words else ""
    name = os.path.basename(program)
    return program == sys.executable or name.startswith(("python", "fabric-", "pytest"))
