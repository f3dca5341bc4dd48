"""Programs on the wire: Program <-> ProgramMsg, content-addressed artifacts, fetching by id."""
from __future__ import annotations

import hashlib
from collections.abc import Iterable, Iterator
from typing import cast

import numpy as np

from fabric import schemas as s
from fabric.motion.program import COLUMNS, JOINTS, Program, column_spec
from fabric.motion.program_file import column_pieces
from fabric.wire import codec
from fabric.wire.errors import DecodeError, ValidationError

__all__ = ["program_to_msg", "program_from_msg", "program_artifact", "program_artifact_pieces",
           "program_from_artifact", "content_id", "PROGRAM_MEDIA_TYPE"]

PROGRAM_MEDIA_TYPE = "application/x-am-fabric-program+msgpack"


def content_id(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def program_to_msg(program: Program) -> s.ProgramMsg:
    return s.ProgramMsg(columns=program.columns(), wobj=program.wobj, meta=dict(program.meta))


def program_from_msg(msg: s.ProgramMsg) -> Program:
    """Rebuild and check a program: every column present, with the right dtype and shape."""
    missing = [c for c in COLUMNS if c not in msg.columns]
    if missing:
        raise ValidationError(f"program lacks column '{missing[0]}'", field=f"columns.{missing[0]}")
    unknown = [c for c in msg.columns if c not in COLUMNS]
    if unknown:
        raise ValidationError(f"unknown program column '{unknown[0]}'", field=f"columns.{unknown[0]}")
    cols = {}
    n = len(msg.columns["op"])
    q = msg.columns[JOINTS]
    nq = int(q.shape[1]) if q.ndim == 2 and 1 <= q.shape[1] <= 32 else 6     # any arm: 1..32 joints a row
    for name, (dtype, shape) in column_spec(nq).items():
        arr = msg.columns[name]
        if arr.dtype != np.dtype(dtype) or arr.shape != (n, *shape):
            raise ValidationError(f"program column '{name}' has dtype {arr.dtype} shape {arr.shape}, "
                                  f"expected {dtype} {(n, *shape)}", field=f"columns.{name}")
        cols[name] = arr
    return Program(**cols, wobj=msg.wobj, meta=msg.meta)


def program_artifact(program: Program, name: str = "program") -> s.Artifact:
    data = codec.encode(program_to_msg(program))
    return s.Artifact(artifact_id=content_id(data), name=name, media_type=PROGRAM_MEDIA_TYPE, data=data)


def program_artifact_pieces(program: Program, name: str = "program") -> tuple[str, list[codec.Buffer]]:
    """The program as an artifact to store, without building it in memory: its id and the pieces of
    the encoded :class:`~fabric.schemas.Artifact` (the same bytes as ``codec.encode(program_artifact(...))``,
    the columns referenced, not copied; see ``ArtifactStore.put_encoded``). For million-row programs,
    whose artifact is some 160 MB."""
    body = codec.encode_pieces(program_to_msg(program))
    digest = hashlib.sha256()
    for piece in _paged(body):
        digest.update(piece)
    artifact_id = digest.hexdigest()
    # the codec writes a Spliced as the bytes field it stands in for (the body is never joined)
    art = s.Artifact(artifact_id=artifact_id, name=name, media_type=PROGRAM_MEDIA_TYPE,
                     data=cast(bytes, codec.Spliced(body)))
    return artifact_id, _PagedPieces(codec.encode_pieces(art))


_PAGED_BYTES = 1 << 16       # arrays from this size on go through column_pieces


class _PagedPieces(list):
    """Pieces of an encoded message that, iterated, give a large column in parts (the same bytes): a column
    mapped from a file (:mod:`fabric.motion.program_file`) is then read through, hashed or written, with
    one part of it resident at a time, not the whole. (A list still: joined, it is the whole message.)"""

    def __iter__(self) -> Iterator[codec.Buffer]:
        return _paged(list.__iter__(self))


def _paged(pieces: Iterable[codec.Buffer]) -> Iterator[codec.Buffer]:
    """The pieces, each view of an array's data as parts of it (:func:`column_pieces`: a mapped one's pages
    given back as it is read)."""
    for piece in pieces:
        arr = piece.obj if isinstance(piece, memoryview) else None
        if isinstance(arr, np.ndarray) and arr.nbytes == piece.nbytes and piece.nbytes >= _PAGED_BYTES:
            yield from column_pieces(arr)
        else:
            yield piece


def program_from_artifact(art: s.Artifact) -> Program:
    if art.media_type != PROGRAM_MEDIA_TYPE:
        raise DecodeError(f"artifact {art.artifact_id} is {art.media_type}, not a program")
    if content_id(art.data) != art.artifact_id:
        raise DecodeError(f"artifact {art.artifact_id} does not match its content hash")
    return program_from_msg(codec.decode(art.data, s.ProgramMsg))
