"""Input files the user names: size checked before a byte is read; small ones inline, large ones uploaded in pieces.

The limit is the environment's ``FABRIC_MAX_INPUT_MB`` (in MiB, 2^20 bytes), else
512 MiB for G-code and 256 MiB for a model (:mod:`fabric.schemas.upload`: the most
the planner and the slicer accept); a caller of these functions may pass its own.
The error of a file above it says which limit it is. An empty file is an error
naming it. A file larger than ``INLINE_MAX_BYTES`` is not read here: it goes to
the service's ``upload`` endpoint in pieces of a few MiB (memory stays bounded in
the CLI and the hub).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fabric.client import Client, input_size
from fabric.schemas.upload import INLINE_MAX_BYTES, MAX_GCODE_BYTES, MAX_MODEL_BYTES, MIB
from fabric.wire.errors import ConfigError, GcodeError, MeshError

__all__ = ["LargeInput", "read_input", "read_whole", "input_limit", "gcode_source", "model_source", "submit_source",
           "GCODE_SUFFIXES", "LIMIT_ENV"]

GCODE_SUFFIXES = (".gcode", ".gco", ".g", ".nc")
LIMIT_ENV = "FABRIC_MAX_INPUT_MB"


@dataclass(frozen=True)
class LargeInput:
    """A file too large to travel inside one request: it is uploaded in pieces when the request is made."""

    path: str
    size: int
    max_bytes: int


def input_limit(path: str, max_size_mb: float | None = None) -> int:
    """The size limit of an input (bytes): ``max_size_mb``, else ``FABRIC_MAX_INPUT_MB``, else by kind."""
    return _limit(path, max_size_mb)[0]


def _limit(path: str, max_size_mb: float | None) -> tuple[int, str]:
    """The size limit of an input (bytes) and where it comes from, in words."""
    hint = ""
    if max_size_mb is None and os.environ.get(LIMIT_ENV):
        raw = os.environ[LIMIT_ENV]
        try:
            max_size_mb = float(raw)
        except ValueError:
            raise ConfigError(f"{LIMIT_ENV} must be a number of MiB, got {raw!r}", field=LIMIT_ENV,
                              value=raw) from None
        hint = f"as {LIMIT_ENV}={raw} sets it"
    if max_size_mb is not None:
        if not (0 < max_size_mb <= 1 << 20):
            raise ConfigError(f"the input size limit must be in (0, 1048576] MiB, got {max_size_mb}",
                              field="max_size_mb", value=max_size_mb)
        return int(max_size_mb * MIB), hint
    if _is_gcode(path):
        return MAX_GCODE_BYTES, "the most the planner accepts"
    return MAX_MODEL_BYTES, "the most the slicer accepts"


def _is_gcode(path: str) -> bool:
    return Path(path).suffix.lower() in GCODE_SUFFIXES


def _checked_size(path: str, max_size_mb: float | None) -> tuple[int, int]:
    """(size, limit) of an input, checked before it is read: within the limit, and not empty."""
    limit, hint = _limit(path, max_size_mb)
    size = input_size(path, limit, hint)
    if size == 0:
        if _is_gcode(path):
            raise GcodeError(f"{path} is empty: there is no G-code in it", file=str(path))
        raise MeshError(f"{path} is empty: there is no model in it", file=str(path), reason="empty")
    return size, limit


def read_input(path: str, max_size_mb: float | None = None) -> bytes | LargeInput:
    """An input file: its bytes when small, a :class:`LargeInput` to upload when larger than
    ``INLINE_MAX_BYTES``; its size checked against the limit first (ValidationError ``size``), an empty
    file refused (GcodeError, or MeshError ``empty`` for a model)."""
    size, limit = _checked_size(path, max_size_mb)
    if size > INLINE_MAX_BYTES:
        return LargeInput(path, size, limit)
    return Path(path).read_bytes()


def read_whole(path: str, max_size_mb: float | None = None) -> bytes:
    """An input file's bytes, whatever its size within the limit (checked first): for requests that carry
    it whole (``JobSubmit``); an empty file is refused as by :func:`read_input`."""
    _checked_size(path, max_size_mb)
    return Path(path).read_bytes()


def gcode_source(c: Client, data: bytes | LargeInput) -> dict[str, Any]:
    """The PlanRequest fields naming the G-code: inline, or uploaded to the planner now."""
    if isinstance(data, LargeInput):
        return {"upload_id": c.upload("planner", data.path, data.max_bytes)}
    return {"gcode": data}


def model_source(c: Client, data: bytes | LargeInput) -> dict[str, Any]:
    """The SliceRequest fields naming the model: inline, or uploaded to the slicer now."""
    if isinstance(data, LargeInput):
        return {"model": b"", "upload_id": c.upload("slicer", data.path, data.max_bytes)}
    return {"model": data}


def submit_source(c: Client, data: bytes | LargeInput) -> dict[str, Any]:
    """The JobSubmit fields naming the file to print: inline, or uploaded to the supervisor now."""
    if isinstance(data, LargeInput):
        return {"model": b"", "upload_id": c.upload("supervisor", data.path, data.max_bytes)}
    return {"model": data}
