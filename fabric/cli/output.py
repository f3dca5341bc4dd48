"""CLI output: ``--json`` for scripts, short readable text for people."""
from __future__ import annotations

import json
import sys
from collections.abc import Callable
from typing import Any, TextIO

import numpy as np

from fabric.schemas import to_plain

__all__ = ["emit", "jsonable", "fail", "StatusLine"]


def jsonable(value: Any) -> Any:
    """Plain JSON values: arrays become lists, bytes become their length."""
    value = to_plain(value)
    if isinstance(value, dict):
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (bytes, bytearray)):
        return {"bytes": len(value)}
    return value


def emit(obj: Any, as_json: bool, human: Callable[[Any], str] | None = None) -> None:
    if as_json:
        print(json.dumps(jsonable(obj), indent=None, separators=(",", ":")))
    elif human is not None:
        print(human(obj))
    else:
        print(_default_text(jsonable(obj)))


def _default_text(value: Any, indent: str = "") -> str:
    if isinstance(value, dict):
        lines = []
        for k, v in value.items():
            if isinstance(v, (dict, list)) and v and not _flat_list(v):
                lines.append(f"{indent}{k}:")
                lines.append(_default_text(v, indent + "  "))
            else:
                lines.append(f"{indent}{k}: {_fmt(v)}")
        return "\n".join(lines)
    if isinstance(value, list):
        return "\n".join(_list_item(v, indent) for v in value)
    return f"{indent}{_fmt(value)}"


def _list_item(v: Any, indent: str) -> str:
    """A list entry: '- ' before its first line, its other lines aligned under it."""
    if not isinstance(v, dict):
        return f"{indent}- {_fmt(v)}"
    text = _default_text(v, indent + "  ")
    return indent + "- " + text[len(indent) + 2:]


def _flat_list(v: Any) -> bool:
    return isinstance(v, list) and all(isinstance(x, (int, float, str, bool)) for x in v)


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}" if abs(v) < 1e5 else f"{v:.1f}"
    if isinstance(v, list) and _flat_list(v):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)


def fail(message: str, as_json: bool, code: str = "error", details: dict | None = None) -> int:
    """Report an error (to stderr, or as JSON on stdout) and return the exit code 1."""
    if as_json:
        print(json.dumps({"error": {"code": code, "message": message, "details": jsonable(details or {})}}))
    else:
        print(f"error [{code}]: {message}", file=sys.stderr)
    return 1


class StatusLine:
    """A status line redrawn in place on stderr when stderr is a terminal; leaving the ``with`` block ends it with
    a newline if anything was drawn, error or not, so what is printed next (the result, or ``error [...]``) starts
    on its own line. Piped (a log, CI), nothing is redrawn: each change of what ``draw`` calls ``piped`` is one
    plain line, so a log reads ``planning`` once, not a hundred percentages glued by carriage returns."""

    def __init__(self, out: TextIO | None = None, tty: bool | None = None) -> None:
        self.out = out if out is not None else sys.stderr
        self.tty = self.out.isatty() if tty is None else tty
        self.open = False
        self._piped_last: str | None = None

    def draw(self, text: str, piped: str | None = None) -> None:
        """Show ``text``; piped, print ``piped`` (default ``text``) as a line when it differs from the last one."""
        if self.tty:
            print(f"\r{text}", end="", file=self.out, flush=True)
            self.open = True
            return
        line = (text if piped is None else piped).rstrip()
        if line != self._piped_last:
            self._piped_last = line
            print(line, file=self.out, flush=True)

    def __enter__(self) -> StatusLine:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.open:
            print(file=self.out, flush=True)
            self.open = False
