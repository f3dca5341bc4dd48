"""Large inputs sent in chunks: a G-code file or a model travels as pieces of a few MiB, assembled on disk.

One giant message would be held whole by the sender, the hub (a Zenoh router)
and the receiver; pieces of at most ``UPLOAD_CHUNK_MAX_BYTES`` keep every
process bounded. The client checks the file's size against the limit before
reading a byte (``MAX_GCODE_BYTES``, ``MAX_MODEL_BYTES``, configurable).
Sizes: a MiB is 2^20 bytes (``MIB``).
"""
from __future__ import annotations

from fabric.schemas.base import f, schema
from fabric.schemas.ids import UPLOAD_ID_PATTERN

__all__ = ["UploadChunk", "UploadStatus", "UPLOAD_CHUNK_MAX_BYTES", "UPLOAD_CHUNK_BYTES", "MAX_GCODE_BYTES",
           "MAX_MODEL_BYTES", "MAX_SUBMIT_BYTES", "INLINE_MAX_BYTES", "MIB"]

MIB = 1 << 20                         # a mebibyte: every size the protocol states in MiB counts these
UPLOAD_CHUNK_MAX_BYTES = 8 * MIB      # the largest piece a service takes
UPLOAD_CHUNK_BYTES = 4 * MIB          # what the client sends
INLINE_MAX_BYTES = 4 * MIB            # the client sends larger inputs by upload, smaller ones inside the request
MAX_GCODE_BYTES = 512 * MIB           # the largest G-code a service takes (inline or uploaded); the client's default
MAX_MODEL_BYTES = 256 * MIB           # the largest model (STL, OBJ, 3MF) a service takes, likewise
MAX_SUBMIT_BYTES = max(MAX_GCODE_BYTES, MAX_MODEL_BYTES)    # a submitted file: G-code or a model


@schema("upload.Chunk")
class UploadChunk:
    """Bytes ``[offset, offset + len(data))`` of an input of ``total_bytes``; offset 0 starts (or restarts)
    the upload, every next offset is where the last piece ended. The last piece carries ``sha256`` of the
    whole input, which the service checks before the upload can be used."""
    upload_id: str = f(max_len=64, pattern=UPLOAD_ID_PATTERN)   # the sender's name for the upload, 8 to 64 of
                                                                # ``A-Za-z0-9_-``
    offset: int = f(ge=0)           # where ``data`` goes in the input (0 starts the upload)
    total_bytes: int = f(ge=0)      # the whole input's size, the same in every piece
    data: bytes = f(default=b"", max_len=UPLOAD_CHUNK_MAX_BYTES)    # this piece of the input
    sha256: str = f(default="", max_len=64)     # on the last piece only: sha256 of the whole input (hex)


@schema("upload.Status")
class UploadStatus:
    """How far an upload has got; name ``upload_id`` in the request (``upload_id`` field) once ``done``."""
    upload_id: str                  # the upload's id, as sent
    received_bytes: int             # bytes received so far (the next piece's ``offset``)
    done: bool = False              # the whole input arrived and its sha256 matched: it can be used
