"""The one msgpack codec: schema instances <-> bytes, with packed ndarrays.

Wire format (documented in docs/protocol.md): a msgpack map holding the
message's fields plus ``"_t"`` (type name) and ``"_v"`` (schema version).
An ``np.ndarray`` field travels as the map ``{"nd": true, "dtype": "<f8",
"shape": [n, 3], "data": <bin, C order>}`` so bulk data is never a list of
floats and any msgpack + numpy reader can rebuild it with ``np.frombuffer``.
A ``common.Empty`` message decodes as any type whose fields all have
defaults: a command that grows arguments still answers older clients.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any, TypeVar

import msgpack
import numpy as np

from fabric.schemas.base import REGISTRY, to_plain, validate_into
from fabric.wire.errors import DecodeError

__all__ = ["encode", "encode_pieces", "Spliced", "decode", "decode_any", "pack", "unpack", "MAX_ARRAY_BYTES"]

T = TypeVar("T")
MAX_ARRAY_BYTES = 1 << 30          # refuse absurd arrays before allocating
_ALLOWED_DTYPES = {"<f8", "<f4", "<i8", "<i4", "<i2", "|i1", "|u1", "<u2", "<u4", "<u8", "|b1"}


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
    if dtype not in _ALLOWED_DTYPES or not isinstance(data, bytes):
        raise DecodeError(f"bad packed array: dtype {dtype!r}", dtype=str(dtype))
    if not isinstance(shape, list) or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in shape):
        raise DecodeError(f"bad packed array shape {shape!r}")
    dt = np.dtype(dtype)
    count = int(np.prod(shape, dtype=np.int64)) if shape else 1
    if count * dt.itemsize != len(data) or len(data) > MAX_ARRAY_BYTES:
        raise DecodeError(f"packed array of shape {shape} and dtype {dtype} does not match {len(data)} bytes")
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
        raise DecodeError(f"payload is not valid msgpack: {exc}", reason=type(exc).__name__) from exc


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
    """Decode ``data`` as a message of type ``expected``, validating every field."""
    body = unpack(data)
    if not isinstance(body, dict):
        raise DecodeError(f"payload is a {type(body).__name__}, expected a {expected.TYPE} map",  # type: ignore[attr-defined]
                          expected=expected.TYPE)  # type: ignore[attr-defined]
    tname, version = body.get("_t"), body.get("_v")
    if tname == "common.Empty" and body.keys() <= {"_t", "_v"} and _all_optional(expected):
        # a request that grew arguments (supervisor/jobs: common.Empty -> JobsQuery): an older client's
        # empty request is the new one with every field at its default
        return validate_into(expected, {})
    if tname != expected.TYPE:  # type: ignore[attr-defined]
        raise DecodeError(f"payload is a {tname!r} message, expected {expected.TYPE}",  # type: ignore[attr-defined]
                          got=str(tname), expected=expected.TYPE)  # type: ignore[attr-defined]
    if not isinstance(version, int) or isinstance(version, bool) or not 1 <= version <= expected.VERSION:  # type: ignore[attr-defined]
        raise DecodeError(f"{tname} version {version!r} is not supported (this side speaks up to "
                          f"v{expected.VERSION})", got=version, supported=expected.VERSION)  # type: ignore[attr-defined]
    return validate_into(expected, body)


def _all_optional(cls: type) -> bool:
    """Whether every field of the schema ``cls`` has a default (so an empty message is a valid one)."""
    return all(not spec.required for spec in cls._SPECS.values())  # type: ignore[attr-defined]


def decode_any(data: bytes) -> Any:
    """Decode a message whose type is read from its ``_t`` tag."""
    body = unpack(data)
    if not isinstance(body, dict) or body.get("_t") not in REGISTRY:
        raise DecodeError("payload has no known message type tag")
    return decode(data, REGISTRY[body["_t"]])

