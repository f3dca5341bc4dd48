"""The one msgpack codec: schema instances <-> bytes, with packed ndarrays.

Wire format (documented in docs/protocol.md): a msgpack map holding the
message's fields plus ``"_t"`` (type name) and ``"_v"`` (schema version).
An ``np.ndarray`` field travels as the map ``{"nd": true, "dtype": "<f8",
"shape": [n, 3], "data": <bin, C order>}`` so bulk data is never a list of
floats and any msgpack + numpy reader can rebuild it with ``np.frombuffer``.
A ``common.Empty`` message decodes as any type whose fields all have
defaults: a command that grows arguments still answers older clients.

Every :class:`~fabric.wire.errors.DecodeError` of :func:`decode` carries
``reason`` (one of ``DECODE_REASONS``) and ``expected`` (the message type
asked for); a wrong type also ``got`` (the ``_t`` received), a version this
side does not speak ``got`` (the ``_v`` received) and ``supported``.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any, TypeVar

import msgpack
import numpy as np

from fabric.schemas.base import REGISTRY, to_plain, validate_into
from fabric.wire.errors import DecodeError

__all__ = ["encode", "encode_pieces", "Spliced", "decode", "decode_any", "pack", "unpack", "MAX_ARRAY_BYTES",
           "PACKED_DTYPES", "DECODE_REASONS"]

T = TypeVar("T")
MAX_ARRAY_BYTES = 1 << 30          # refuse absurd arrays before allocating
PACKED_DTYPES = frozenset({"<f8", "<f4", "<i8", "<i4", "<i2", "|i1", "|u1", "<u2", "<u4", "<u8", "|b1"})
"""The dtypes a packed array may have (numpy's ``dtype.str``: little-endian, or one byte)."""

DECODE_REASONS = ("empty", "msgpack", "not_map", "array", "type", "version")
"""Why a payload is not a message (``DecodeError.details['reason']``): no bytes at all, bytes that are not
msgpack, msgpack that is not a map, a packed array that does not add up, a map of another type (``_t``),
or of a version this side does not speak (``_v``: newer than it knows, or not a positive integer)."""


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        arr = np.ascontiguousarray(obj)
        if arr.dtype.byteorder == ">":
            arr = arr.astype(arr.dtype.newbyteorder("<"))
        return {"nd": True, "dtype": arr.dtype.str, "shape": list(arr.shape), "data": arr.tobytes()}
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot encode {type(obj).__name__}")


def _hook(obj: dict) -> Any:
    if obj.get("nd") is True and "data" in obj:
        return _unpack_array(obj)
    return obj


def _unpack_array(obj: dict) -> np.ndarray:
    dtype, shape, data = obj.get("dtype"), obj.get("shape"), obj.get("data")
    if dtype not in PACKED_DTYPES or not isinstance(data, bytes):
        raise DecodeError(f"bad packed array: dtype {dtype!r}", reason="array", dtype=str(dtype))
    if not isinstance(shape, list) or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in shape):
        raise DecodeError(f"bad packed array shape {shape!r}", reason="array")
    dt = np.dtype(dtype)
    count = int(np.prod(shape, dtype=np.int64)) if shape else 1
    if count * dt.itemsize != len(data) or len(data) > MAX_ARRAY_BYTES:
        raise DecodeError(f"packed array of shape {shape} and dtype {dtype} does not match {len(data)} bytes",
                          reason="array")
    return np.frombuffer(data, dtype=dt).reshape(shape)


def pack(value: Any) -> bytes:
    """Encode plain values (with ndarrays) as msgpack."""
    return msgpack.packb(value, default=_default, use_bin_type=True)


def unpack(data: bytes) -> Any:
    """Decode msgpack bytes into plain values (packed arrays rebuilt); DecodeError on garbage."""
    try:
        return msgpack.unpackb(data, object_hook=_hook, raw=False, strict_map_key=False,
                               max_bin_len=MAX_ARRAY_BYTES, max_str_len=1 << 26)
    except DecodeError:
        raise
    except (msgpack.ExtraData, msgpack.FormatError, msgpack.StackError, ValueError, TypeError) as exc:
        raise DecodeError(f"payload is not valid msgpack: {type(exc).__name__} {exc}".rstrip(),
                          reason="msgpack") from exc


def encode(msg: Any) -> bytes:
    """Encode a schema instance with its type tag and version. A field given as :class:`Spliced` pieces
    (a bulk reply) is copied once, into the message's bytes."""
    body = to_plain(msg)
    body["_t"], body["_v"] = msg.TYPE, msg.VERSION
    if any(isinstance(v, Spliced) for v in body.values()):
        return b"".join(_pieces_of(body))
    return pack(body)


Buffer = bytes | bytearray | memoryview
_BIG_BYTES = 1 << 16            # bytes fields at least this long are referenced, not copied


class Spliced:
    """Bytes given as pieces (already encoded elsewhere), packed by :func:`encode_pieces` as one bin
    field without joining them (e.g. a large artifact's data)."""

    def __init__(self, pieces: Sequence[Buffer]) -> None:
        self.pieces = pieces
        self.size = sum(memoryview(p).nbytes for p in pieces)


def encode_pieces(msg: Any) -> list[Buffer]:
    """The bytes of :func:`encode` (``b"".join`` of the result equals them) as pieces: the data of every
    array and of every large bytes field is a view of the caller's memory, never copied. For writing a
    large message to a file or a hash without building it whole. The caller keeps ``msg`` unchanged
    until the pieces are used."""
    body = to_plain(msg)
    body["_t"], body["_v"] = msg.TYPE, msg.VERSION
    return _pieces_of(body)


def _pieces_of(body: dict) -> list[Buffer]:
    out: list[Buffer] = []
    _pieces(body, out, msgpack.Packer(default=_default, use_bin_type=True))
    return out


def _pieces(value: Any, out: list[Buffer], packer: msgpack.Packer) -> None:
    if isinstance(value, dict):
        out.append(packer.pack_map_header(len(value)))
        for k, v in value.items():
            _pieces(k, out, packer)
            _pieces(v, out, packer)
    elif isinstance(value, (list, tuple)):
        out.append(packer.pack_array_header(len(value)))
        for v in value:
            _pieces(v, out, packer)
    elif isinstance(value, np.ndarray):
        arr = np.ascontiguousarray(value)
        if arr.dtype.byteorder == ">":
            arr = arr.astype(arr.dtype.newbyteorder("<"))
        data = arr.data.cast("B") if arr.size else b""
        _pieces({"nd": True, "dtype": arr.dtype.str, "shape": list(arr.shape), "data": Spliced([data])}, out, packer)
    elif isinstance(value, Spliced):
        out.append(_bin_header(value.size))
        out.extend(value.pieces)
    elif isinstance(value, (bytes, bytearray, memoryview)) and memoryview(value).nbytes >= _BIG_BYTES:
        out.append(_bin_header(memoryview(value).nbytes))
        out.append(value)
    else:
        out.append(packer.pack(value))


def _bin_header(size: int) -> bytes:
    """msgpack's header of a bin of ``size`` bytes (the smallest form, as the packer writes it)."""
    if size < 1 << 8:
        return b"\xc4" + size.to_bytes(1, "big")
    if size < 1 << 16:
        return b"\xc5" + size.to_bytes(2, "big")
    if size < 1 << 32:
        return b"\xc6" + size.to_bytes(4, "big")
    raise ValueError(f"a bin of {size} bytes is beyond msgpack's 4 GiB")


def decode(data: bytes, expected: type[T]) -> T:
    """Decode ``data`` as a message of type ``expected``, validating every field. A message of a version newer
    than this side's is refused whatever its type (``common.Empty`` taken for an all-default request too)."""
    want: str = expected.TYPE  # type: ignore[attr-defined]
    if not data:
        raise DecodeError(f"the payload is empty, expected a {want} map: a request without arguments is "
                          f"common.Empty, the map {{\"_t\": \"common.Empty\", \"_v\": 1}}", reason="empty",
                          expected=want)
    try:
        body = unpack(data)
    except DecodeError as err:
        err.details.setdefault("expected", want)
        raise
    if not isinstance(body, dict):
        raise DecodeError(f"payload is a {type(body).__name__}, expected a {want} map", reason="not_map",
                          expected=want)
    tname = body.get("_t")
    if tname == "common.Empty" and body.keys() <= {"_t", "_v"} and _all_optional(expected):
        # a request that grew arguments (supervisor/jobs: common.Empty -> JobsQuery): an older client's
        # empty request is the new one with every field at its default
        _check_version(body, REGISTRY["common.Empty"], want)
        return validate_into(expected, {})
    if tname != want:
        raise DecodeError(f"payload is a {tname!r} message, expected {want}", reason="type", got=str(tname),
                          expected=want)
    _check_version(body, expected, want)
    return validate_into(expected, body)


def _check_version(body: dict, cls: type, want: str) -> None:
    """Refuse a ``_v`` this side does not speak for the message type ``cls``: not an integer from 1 to its own."""
    version, newest = body.get("_v"), cls.VERSION  # type: ignore[attr-defined]
    if not isinstance(version, int) or isinstance(version, bool) or not 1 <= version <= newest:
        raise DecodeError(f"{body.get('_t')} version {version!r} is not supported (this side speaks up to "
                          f"v{newest})", reason="version", got=version, supported=newest, expected=want)


def _all_optional(cls: type) -> bool:
    """Whether every field of the schema ``cls`` has a default (so an empty message is a valid one)."""
    return all(not spec.required for spec in cls.SPECS.values())  # type: ignore[attr-defined]


def decode_any(data: bytes) -> Any:
    """Decode a message whose type is read from its ``_t`` tag."""
    body = unpack(data) if data else None
    if not isinstance(body, dict) or body.get("_t") not in REGISTRY:
        got = body.get("_t") if isinstance(body, dict) else None
        raise DecodeError("payload has no known message type tag", reason="type", got=str(got), expected="")
    return decode(data, REGISTRY[body["_t"]])

