"""Input files the user names: size checked before a byte is read; small ones inline, large ones uploaded in pieces.

The limit is ``--max-size-mb`` where a command has it, else the environment's
``FABRIC_MAX_INPUT_MB``, else 512 MB for G-code and 256 MB for a model
(:mod:`fabric.schemas.upload`). A file larger than ``INLINE_MAX_BYTES`` is not
read here: it goes to the service's ``upload`` endpoint in pieces of a few MB
(memory stays bounded in the CLI, the hub and the service).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fabric.client import Client, input_size
from fabric.wire.errors import ConfigError
from fabric.schemas.upload import INLINE_MAX_BYTES, MAX_GCODE_BYTES, MAX_MODEL_BYTES

__all__ = ["LargeInput", "read_input", "read_whole", "input_limit", "gcode_source", "model_source", "GCODE_SUFFIXES",
           "LIMIT_ENV"]

GCODE_SUFFIXES = (".gcode", ".gco", ".g", ".nc")
LIMIT_ENV = "FABRIC_MAX_INPUT_MB"


@dataclass(frozen=True)
class LargeInput:
    """A file too large to travel inside one request: it is uploaded in pieces when the request is made."""

    path: str
    size: int
    max_bytes: int


def input_limit(path: str, max_size_mb: float | None = None) -> int:
    """The size limit of an input (bytes): the option, else ``FABRIC_MAX_INPUT_MB``, else by kind."""
    if max_size_mb is None and os.environ.get(LIMIT_ENV):
        raw = os.environ[LIMIT_ENV]
        try:
            max_size_mb = float(raw)
        except ValueError:
            raise ConfigError(f"{LIMIT_ENV} must be a number of MB, got {raw!r}", field=LIMIT_ENV, value=raw) from None
    if max_size_mb is not None:
        if not (0 < max_size_mb <= 1 << 20):
            raise ConfigError(f"the input size limit must be in (0, 1048576] MB, got {max_size_mb}",
                              field="max_size_mb", value=max_size_mb)
        return int(max_size_mb * 2**20)
    return MAX_GCODE_BYTES if Path(path).suffix.lower() in GCODE_SUFFIXES else MAX_MODEL_BYTES


def read_input(path: str, max_size_mb: float | None = None) -> bytes | LargeInput:
    """An input file: its bytes when small, a :class:`LargeInput` to upload when larger than
    ``INLINE_MAX_BYTES``; its size checked against the limit first (ValidationError ``size``)."""
    limit = input_limit(path, max_size_mb)
    size = input_size(path, limit)
    if size > INLINE_MAX_BYTES:
        return LargeInput(path, size, limit)
    return Path(path).read_bytes()


def read_whole(path: str, max_size_mb: float | None = None) -> bytes:
    """An input file's bytes, whatever its size within the limit (checked first): for requests that carry
    it whole (``JobSubmit``)."""
    input_size(path, input_limit(path, max_size_mb))
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
