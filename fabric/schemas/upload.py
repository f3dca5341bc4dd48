"""Large inputs sent in chunks: a G-code file or a model travels as pieces of a few MB, assembled on disk.

One giant message would be held whole by the sender, the hub (a Zenoh router)
and the receiver; pieces of at most ``UPLOAD_CHUNK_MAX_BYTES`` keep every
process bounded. The client checks the file's size against the limit before
reading a byte (``MAX_GCODE_BYTES``, ``MAX_MODEL_BYTES``, configurable).
"""
from __future__ import annotations

from fabric.schemas.base import f, schema

__all__ = ["UploadChunk", "UploadStatus", "UPLOAD_CHUNK_MAX_BYTES", "UPLOAD_CHUNK_BYTES", "MAX_GCODE_BYTES",
           "MAX_MODEL_BYTES", "INLINE_MAX_BYTES", "UPLOAD_ID_PATTERN"]

UPLOAD_CHUNK_MAX_BYTES = 8 << 20      # the largest piece a service takes
UPLOAD_CHUNK_BYTES = 4 << 20          # what the client sends
INLINE_MAX_BYTES = 4 << 20            # smaller inputs travel inside the request itself
MAX_GCODE_BYTES = 512 << 20           # default limits, checked by the client up front and by the service
MAX_MODEL_BYTES = 256 << 20
UPLOAD_ID_PATTERN = r"[A-Za-z0-9_-]{8,64}"


@schema("upload.Chunk")
class UploadChunk:
    """Bytes ``[offset, offset + len(data))`` of an input of ``total_bytes``; offset 0 starts (or restarts)
    the upload, every next offset is where the last piece ended. The last piece carries ``sha256`` of the
    whole input, which the service checks before the upload can be used."""
    upload_id: str = f(max_len=64)  # the sender's name for the upload, 8 to 64 of ``A-Za-z0-9_-``
    offset: int = f(ge=0)           # where ``data`` goes in the input (0 starts the upload)
    total_bytes: int = f(ge=0)      # the whole input's size, the same in every piece
    data: bytes = b""               # at most 8 MB (``UPLOAD_CHUNK_MAX_BYTES``); the client sends 4 MB pieces
    sha256: str = f(default="", max_len=64)     # on the last piece only: sha256 of the whole input (hex)


@schema("upload.Status")
class UploadStatus:
    """How far an upload has got; name ``upload_id`` in the request (``upload_id`` field) once ``done``."""
    upload_id: str                  # the upload's id, as sent
    received_bytes: int             # bytes received so far (the next piece's ``offset``)
    done: bool = False              # the whole input arrived and its sha256 matched: it can be used
