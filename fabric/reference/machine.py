"""The machine-readable protocol description (docs/protocol.json): JSON Schema per message, plus the tables.

One JSON document. Its ``$defs`` hold a JSON Schema (draft 2020-12) per message type,
built from the schema classes' field specs (type, range, choices, length, array
dtype and shape, default, required) and descriptions; ``endpoints``, ``topics``,
``artifacts``, ``keys``, ``errors`` and ``events`` are the tables a client generator
needs. msgpack maps onto JSON as msgpack's own JSON view, except ``bin``, which is
base64 text here (``$defs/bin``). A message on the wire is its type's schema plus
the two tags (``$defs/envelope``): validate a payload against
``{"allOf": [{"$ref": "#/$defs/<type>"}, {"$ref": "#/$defs/envelope"}]}``. A
message nested inside another carries no tags.
"""
from __future__ import annotations

import base64
import dataclasses
import types
import typing
from typing import Any, Union

import numpy as np

from fabric.reference.events import EVENTS, JOB_DATA
from fabric.reference.fields import field_docs, json_default, message_doc

__all__ = ["message_schemas", "to_json_value", "describe", "event_data_schema", "SCHEMA_DIALECT"]

SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
BIN = {"type": "string", "contentEncoding": "base64", "x-msgpack": "bin",
       "description": "msgpack bin, as base64 text."}
ENVELOPE = {"type": "object", "required": ["_t", "_v"],
            "description": "A message on the wire: its fields plus the tags _t (type) and _v (version)."}


def _packed_array(dtypes: list[str]) -> dict[str, Any]:
    return {"type": "object", "required": ["nd", "dtype", "shape", "data"], "additionalProperties": False,
            "description": "A packed array: numpy.frombuffer(data, dtype).reshape(shape), little-endian, C order.",
            "properties": {"nd": {"const": True}, "dtype": {"enum": dtypes},
                           "shape": {"type": "array", "items": {"type": "integer", "minimum": 0}},
                           "data": {"$ref": "#/$defs/bin"}}}


def _ref(name: str) -> dict[str, Any]:
    return {"$ref": f"#/$defs/{name}"}


def _type_schema(tp: Any, spec: Any | None) -> dict[str, Any]:
    """JSON Schema of a field's annotation; ``spec`` (range, choices, length) applies to scalars and list items."""
    origin = typing.get_origin(tp)
    if origin in (Union, types.UnionType):
        inner = [a for a in typing.get_args(tp) if a is not type(None)]
        return {"anyOf": [_type_schema(inner[0], spec), {"type": "null"}]}
    if tp is Any:
        return {}
    if tp is np.ndarray:
        out: dict[str, Any] = {"$ref": "#/$defs/packed_array"}
        extra: dict[str, Any] = {}
        if spec is not None and spec.dtype:
            extra["dtype"] = {"const": np.dtype(spec.dtype).str}
        if spec is not None and spec.shape:
            extra["shape"] = {"prefixItems": [{} if d is None else {"const": d} for d in spec.shape],
                              "minItems": len(spec.shape), "maxItems": len(spec.shape)}
        return {"allOf": [out, {"properties": extra}]} if extra else out
    if origin is list:
        (item,) = typing.get_args(tp)
        arr: dict[str, Any] = {"type": "array", "items": _type_schema(item, spec)}
        if spec is not None and spec.shape and len(spec.shape) == 1 and spec.shape[0] is not None:
            arr["minItems"] = arr["maxItems"] = spec.shape[0]
        return arr
    if origin is dict:
        return {"type": "object", "additionalProperties": _type_schema(typing.get_args(tp)[1], None)}
    if isinstance(tp, type) and hasattr(tp, "TYPE"):
        return _ref(tp.TYPE)
    if tp is bytes:
        return _bin_schema(spec)
    base: dict[str, Any] = {float: {"type": "number"}, int: {"type": "integer"}, bool: {"type": "boolean"},
                            str: {"type": "string"}}[tp]
    base = dict(base)
    if spec is not None:
        if spec.ge is not None:
            base["minimum"] = spec.ge
        if spec.le is not None:
            base["maximum"] = spec.le
        if spec.choices is not None:
            base["enum"] = list(spec.choices)
        if spec.min_len is not None:
            base["minLength"] = spec.min_len
        if spec.max_len is not None:
            base["maxLength"] = spec.max_len
        if spec.pattern is not None:
            base["pattern"] = f"^(?:{spec.pattern})$"     # JSON Schema's pattern is not anchored; the schema's is
    return base


def _bin_schema(spec: Any | None) -> dict[str, Any]:
    """A ``bin`` field: base64 text here, at most ``spec.max_len`` bytes (as base64: 4 characters per 3 bytes)."""
    out: dict[str, Any] = {"$ref": "#/$defs/bin"}
    if spec is not None and spec.max_len is not None:
        out["maxLength"] = 4 * -(-spec.max_len // 3)
        out["x-max-bytes"] = spec.max_len
    return out


def _message_schema(name: str, cls: type) -> dict[str, Any]:
    version = cls.VERSION  # type: ignore[attr-defined]
    props: dict[str, Any] = {"_t": {"const": name, "description": "the message type."},
                             "_v": {"type": "integer", "minimum": 1, "maximum": version,
                                    "description": "the schema version (see the versioning rule)."}}
    required = []
    for fd in field_docs(cls):
        prop = _type_schema(fd.tp, fd.spec)
        if fd.description:
            prop["description"] = fd.description
        if fd.unit:
            prop["x-unit"] = fd.unit
        if fd.default is not dataclasses.MISSING:
            prop["default"] = json_default(fd.default)
        else:
            required.append(fd.name)
        props[fd.name] = prop
    out: dict[str, Any] = {"title": name, "type": "object", "x-version": cls.VERSION}  # type: ignore[attr-defined]
    doc = message_doc(cls)
    if doc:
        out["description"] = doc
    out.update({"properties": props, "required": required, "patternProperties": {"^_": {}},
                "additionalProperties": False})
    return out


def message_schemas(registry: dict[str, type], dtypes: list[str]) -> dict[str, Any]:
    """``$defs``: a schema per message type, plus ``bin``, ``packed_array`` and ``envelope``."""
    defs: dict[str, Any] = {"bin": BIN, "packed_array": _packed_array(dtypes), "envelope": ENVELOPE}
    for name, cls in sorted(registry.items()):
        defs[name] = _message_schema(name, cls)
    return defs


def event_data_schema(kind: str, job_events: tuple[str, ...]) -> dict[str, Any]:
    """The JSON Schema of an event's ``data`` for ``kind`` (job events may also carry ``job_id``, ``elapsed_s``)."""
    entry = EVENTS[kind]
    data = dict(entry.data)
    optional = set(entry.optional)
    if kind in job_events:
        for key, value in JOB_DATA.items():
            if key not in data:
                data[key] = value
                optional.add(key)
    props = {key: {"type": tp, "description": text} for key, (tp, text) in data.items()}
    return {"type": "object", "properties": props, "required": [k for k in data if k not in optional],
            "additionalProperties": False}


def to_json_value(value: Any) -> Any:
    """A decoded msgpack value (plain: maps, lists, bytes) in the JSON view of this description."""
    if isinstance(value, dict):
        return {str(k): to_json_value(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_json_value(v) for v in value]
    if isinstance(value, (bytes, bytearray, memoryview)):
        return base64.b64encode(bytes(value)).decode()
    if isinstance(value, np.ndarray):
        arr = np.ascontiguousarray(value)
        return {"nd": True, "dtype": arr.dtype.str, "shape": list(arr.shape),
                "data": base64.b64encode(arr.tobytes()).decode()}
    if isinstance(value, np.generic):
        return value.item()
    return value


def describe(parts: dict[str, Any]) -> dict[str, Any]:
    """The whole document, from the parts ``fabric.protocol_doc`` gathers (keys in a fixed order)."""
    return {"$schema": SCHEMA_DIALECT, "$id": "urn:am-fabric:protocol",
            "title": "am-fabric wire protocol",
            "description": __doc__.split("\n\n", 1)[1].replace("\n", " ").strip() if __doc__ else "",
            **parts}
