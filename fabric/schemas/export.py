"""Messages of the planner's streamed export: one bounded chunk of a program's RAPID / KRL / URScript / CSV."""
from __future__ import annotations

from fabric.schemas.base import f, schema
from fabric.schemas.pipeline import EXPORT_FORMATS

__all__ = ["ExportChunkRequest", "ExportChunk", "MAX_CHUNK_BYTES"]

MAX_CHUNK_BYTES = 64 << 20


@schema("planner.ExportChunkRequest", version=2)
class ExportChunkRequest:
    """The next chunk of an export. Offset 0 starts (or restarts) it; every next offset is where the last ended.

    The program is a planned ``program_id``, or the program of the plan job ``job_id`` (``program_id``
    empty): that export starts as soon as the job's program is final, before its cycle time and its id
    are known (the CSV's ``t_s`` column waits for the times). Until then a chunk may come back empty and
    not ``done``: ask again at the same offset."""
    fmt: str = f(choices=EXPORT_FORMATS)        # rapid (ABB), krl (KUKA), urscript (Universal Robots) or csv
    program_id: str = f(default="", max_len=128)    # the planned program (an artifact id of the planner)
    job_id: str = f(default="", max_len=64)     # or the plan job whose program to export (``program_id`` empty)
    offset: int = f(default=0, ge=0)            # byte offset of this chunk in the export
    limit_bytes: int = f(default=4 << 20, ge=4096, le=MAX_CHUNK_BYTES)  # the most bytes this chunk carries
    module_targets: int = f(default=5000, ge=10, le=1_000_000)  # targets per module (robot languages split a
                                                                # long program into modules of this size)


@schema("planner.ExportChunk")
class ExportChunk:
    """Bytes ``[offset, offset + len(data))`` of the export; ``done`` with the last of them."""
    program_id: str                 # the program exported
    fmt: str                        # the format, as asked
    offset: int                     # where ``data`` starts in the export
    data: bytes                     # the next bytes (may be empty and not ``done``: ask again at the same offset)
    done: bool                      # true with the last bytes of the export
    name: str = ""            # a file name for the export (``<program>.<suffix>``)
    media_type: str = ""      # the export's media type (e.g. ``text/csv``)
