"""Typed, versioned message schemas: dataclasses with declared field specs, validated on decode.

A schema is a dataclass decorated with ``@schema("area.Name", version)``. Its
fields are annotated with plain types (``int``, ``float``, ``str``, ``bool``,
``bytes``, ``list[X]``, ``dict[str, X]``, ``X | None``, nested schemas,
``Any`` for free-form plain values) or ``np.ndarray`` for bulk numeric data.
Ranges, choices, lengths, text patterns, the size of a ``bytes`` field and
array dtypes/shapes are declared with :func:`f`.

Validation turns a plain decoded mapping into the dataclass, checking every
field and raising :class:`~fabric.wire.errors.ValidationError` whose
``details['field']`` is the dotted path of the offending field and
``details['schema']`` the message type it was validated as.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import re
import types
import typing
from collections.abc import Callable
from enum import Enum
from typing import TYPE_CHECKING, Any, TypeVar, Union

import numpy as np

from fabric.wire.errors import ValidationError

__all__ = ["schema", "f", "REGISTRY", "validate_into", "to_plain"]

REGISTRY: dict[str, type[Any]] = {}   # type name -> schema class (with TYPE, VERSION and SPECS, its fields, set)
T = TypeVar("T")
_MISSING = dataclasses.MISSING

if TYPE_CHECKING:   # tells type checkers that @schema makes a dataclass (typing has it from 3.11 only)
    from typing_extensions import dataclass_transform
else:
    def dataclass_transform(**_kwargs: Any) -> Callable[[T], T]:
        return lambda fn: fn


def f(default: Any = _MISSING, *, ge: float | None = None, le: float | None = None,
      choices: tuple[Any, ...] | None = None, dtype: str | None = None,
      shape: tuple[int | None, ...] | None = None, factory: Callable[[], Any] | None = None,
      max_len: int | None = None, min_len: int | None = None, pattern: str | None = None) -> Any:
    """Declare a field with constraints (range, choices, ndarray dtype and shape, length, pattern).

    ``max_len`` and ``min_len`` count characters of a ``str`` and bytes of a ``bytes`` field; ``pattern`` is a
    regular expression a ``str`` must match whole (written so that JSON Schema's ``pattern`` reads it alike)."""
    if pattern is not None:
        re.compile(pattern)                 # a bad pattern is a bug in the declaration: fail at import
    meta = {"ge": ge, "le": le, "choices": choices, "dtype": dtype, "shape": shape, "max_len": max_len,
            "min_len": min_len, "pattern": pattern}
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


@dataclasses.dataclass(frozen=True)
class FieldSpec:
    name: str
    tp: Any
    required: bool
    ge: float | None = None
    le: float | None = None
    choices: tuple[Any, ...] | None = None
    dtype: str | None = None
    shape: tuple[int | None, ...] | None = None
    max_len: int | None = None
    min_len: int | None = None
    pattern: str | None = None
    enum: type[Enum] | None = None     # a state field (``fabric.schemas.states``): its strings become members


def _enum_field(tp: Any) -> tuple[Any, type[Enum] | None]:
    """A field annotated with a ``str`` enum (or a list of one) as the wire and the documents see it: ``str``
    (``list[str]``) with that enum's values as its choices; and the enum."""
    item = typing.get_args(tp)[0] if typing.get_origin(tp) is list else tp
    if not (isinstance(item, type) and issubclass(item, Enum) and issubclass(item, str)):
        return tp, None
    return (list[str] if item is not tp else str), item


def _enum_setattr(enums: dict[str, type[Enum]]) -> Callable[[Any, str, Any], None]:
    """A ``__setattr__`` that turns a plain string set on a state field, when the message is built or later, into
    its enum member (``JobRecord(state="queued").state.waiting``): the field holds a member whatever the code
    that set it; a string that is no member is a ValidationError."""
    def setattr_(self: Any, name: str, value: Any) -> None:
        enum = enums.get(name)
        if enum is not None:
            try:
                value = [enum(v) for v in value] if isinstance(value, list) else enum(value)
            except ValueError:
                raise ValidationError(f"field '{name}': '{value}' is not one of {[m.value for m in enum]}",
                                      field=name, schema=type(self).TYPE) from None
        object.__setattr__(self, name, value)
    return setattr_


@dataclass_transform(field_specifiers=(f,))
def schema(type_name: str, version: int = 1) -> Callable[[type[T]], type[T]]:
    """Class decorator: make a dataclass message registered under ``type_name``."""

    def wrap(cls: type[T]) -> type[T]:
        hints = typing.get_type_hints(cls)
        enums = {name: enum for name, (_tp, enum) in ((n, _enum_field(t)) for n, t in hints.items()) if enum}
        if enums:
            cls.__setattr__ = _enum_setattr(enums)             # type: ignore[method-assign]
        dc = dataclasses.dataclass(cls)
        specs = {}
        for fld in dataclasses.fields(dc):  # type: ignore[arg-type]  # typeshed: dataclass() returns type[T]
            required = fld.default is _MISSING and fld.default_factory is _MISSING
            meta = dict(fld.metadata)
            tp, enum = _enum_field(hints[fld.name])
            if enum is not None:
                meta["choices"] = tuple(m.value for m in enum)
                meta["enum"] = enum
            specs[fld.name] = FieldSpec(fld.name, tp, required, **meta)
        dc.TYPE, dc.VERSION, dc.SPECS = type_name, version, specs  # type: ignore[attr-defined]
        if type_name in REGISTRY:
            raise RuntimeError(f"schema {type_name} declared twice")
        REGISTRY[type_name] = dc
        return dc

    return wrap


def validate_into(cls: type[T], data: Any) -> T:
    """Build ``cls`` from a plain mapping, validating every field; a ValidationError names the field
    (``field``, a dotted path) and the message type it was validated as (``schema``)."""
    try:
        return _validate(cls, data, "")
    except ValidationError as err:
        err.details.setdefault("schema", cls.TYPE)  # type: ignore[attr-defined]
        raise


def _validate(cls: type[T], data: Any, path: str) -> T:
    """``validate_into`` for the message ``cls`` at ``path`` inside the one being validated (errors name the
    field by its path from the top; ``validate_into`` adds the top message's type)."""
    if not isinstance(data, dict):
        raise ValidationError(f"{path or cls.TYPE}: expected a map, got {type(data).__name__}",  # type: ignore[attr-defined]
                              field=path)
    specs: dict[str, FieldSpec] = cls.SPECS  # type: ignore[attr-defined]
    unknown = [k for k in data if k not in specs and not (isinstance(k, str) and k.startswith("_"))]
    if unknown:
        name = f"{path}.{unknown[0]}" if path else str(unknown[0])
        raise ValidationError(f"unknown field '{name}' in {cls.TYPE}", field=name)  # type: ignore[attr-defined]
    kwargs = {}
    for name, spec in specs.items():
        fpath = f"{path}.{name}" if path else name
        if name not in data:
            if spec.required:
                raise ValidationError(f"missing field '{fpath}' in {cls.TYPE}", field=fpath)  # type: ignore[attr-defined]
            continue
        kwargs[name] = _check(spec.tp, data[name], fpath, spec)
    return cls(**kwargs)


def _fail(fpath: str, msg: str) -> ValidationError:
    return ValidationError(f"field '{fpath}': {msg}", field=fpath)


def _check(tp: Any, value: Any, fpath: str, spec: FieldSpec | None) -> Any:
    origin = typing.get_origin(tp)
    if tp is Any:
        return value
    if origin in (Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None:
            if type(None) in args:
                return None
            raise _fail(fpath, "must not be null")
        inner = [a for a in args if a is not type(None)]
        return _check(inner[0], value, fpath, spec)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise _fail(fpath, f"expected a number, got {type(value).__name__}")
        value = float(value)
        if math.isnan(value):
            raise _fail(fpath, "is NaN")
        return _range(value, fpath, spec)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _fail(fpath, f"expected an integer, got {type(value).__name__}")
        return _range(value, fpath, spec)
    if tp is bool:
        if not isinstance(value, bool):
            raise _fail(fpath, f"expected a boolean, got {type(value).__name__}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise _fail(fpath, f"expected a string, got {type(value).__name__}")
        if spec and spec.choices is not None and value not in spec.choices:
            raise _fail(fpath, f"'{value}' is not one of {list(spec.choices)}")
        if spec and spec.enum is not None:
            return spec.enum(value)
        return _text(value, fpath, spec)
    if tp is bytes:
        if not isinstance(value, (bytes, bytearray)):
            raise _fail(fpath, f"expected bytes, got {type(value).__name__}")
        if spec and spec.max_len is not None and len(value) > spec.max_len:
            raise _fail(fpath, f"{len(value):,} bytes, more than the {spec.max_len:,} it may hold (send a larger "
                               f"input by upload)")
        return bytes(value)
    if tp is np.ndarray:
        return _array(value, fpath, spec)
    if origin is list:
        if not isinstance(value, (list, tuple)):
            raise _fail(fpath, f"expected a list, got {type(value).__name__}")
        if spec and spec.shape and len(spec.shape) == 1 and spec.shape[0] is not None and len(value) != spec.shape[0]:
            raise _fail(fpath, f"expected {spec.shape[0]} items, got {len(value)}")
        (item,) = typing.get_args(tp)
        sub = FieldSpec(fpath, item, True, ge=spec.ge, le=spec.le, choices=spec.choices, enum=spec.enum) \
            if spec else None
        return [_check(item, v, f"{fpath}[{i}]", sub) for i, v in enumerate(value)]
    if origin is dict:
        if not isinstance(value, dict):
            raise _fail(fpath, f"expected a map, got {type(value).__name__}")
        _, vt = typing.get_args(tp)
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise _fail(fpath, "map keys must be strings")
            out[k] = _check(vt, v, f"{fpath}.{k}", None)
        return out
    if isinstance(tp, type) and hasattr(tp, "SPECS"):
        return _validate(tp, value, fpath)
    raise _fail(fpath, f"unsupported schema type {tp!r}")  # a bug in a schema declaration


def _text(value: str, fpath: str, spec: FieldSpec | None) -> str:
    """A string's length and pattern, as its spec declares them."""
    if spec is None:
        return value
    if spec.max_len is not None and len(value) > spec.max_len:
        raise _fail(fpath, f"longer than {spec.max_len}")
    if spec.min_len is not None and len(value) < spec.min_len:
        raise _fail(fpath, f"'{value}' is shorter than {spec.min_len} characters")
    if spec.pattern is not None and not re.fullmatch(spec.pattern, value):
        raise _fail(fpath, f"'{value[:80]}' does not match {spec.pattern}")
    return value


def _range(value: float, fpath: str, spec: FieldSpec | None) -> Any:
    if spec is None:
        return value
    if spec.ge is not None and value < spec.ge:
        raise _fail(fpath, f"{value} is below the minimum {spec.ge}")
    if spec.le is not None and value > spec.le:
        raise _fail(fpath, f"{value} is above the maximum {spec.le}")
    if spec.choices is not None and value not in spec.choices:
        raise _fail(fpath, f"{value} is not one of {list(spec.choices)}")
    return value


def _array(value: Any, fpath: str, spec: FieldSpec | None) -> np.ndarray:
    if not isinstance(value, np.ndarray):
        raise _fail(fpath, f"expected a packed array, got {type(value).__name__}")
    if spec and spec.dtype and value.dtype != np.dtype(spec.dtype):
        raise _fail(fpath, f"dtype {value.dtype.str}, expected {np.dtype(spec.dtype).str}")
    if spec and spec.shape is not None and (
            value.ndim != len(spec.shape)
            or any(s is not None and s != d for s, d in zip(spec.shape, value.shape, strict=True))):
        raise _fail(fpath, f"shape {value.shape}, expected {spec.shape}")
    if value.dtype.kind == "f" and not np.all(np.isfinite(value)):
        raise _fail(fpath, "contains NaN or infinity")
    return value


_SCALARS = frozenset({int, float, str, bool, bytes, type(None)})   # plain already: returned as they are


def to_plain(msg: Any) -> Any:
    """A schema instance as plain values (ndarrays kept), for encoding or ``--json``."""
    tp = type(msg)
    if tp in _SCALARS:
        return msg
    if isinstance(msg, Enum):          # a state (fabric.schemas.states): its string
        return msg.value
    names = _field_names(tp) if dataclasses.is_dataclass(tp) else None
    if names is not None:
        return {name: to_plain(getattr(msg, name)) for name in names}
    if isinstance(msg, (list, tuple)):
        return [v if type(v) in _SCALARS else to_plain(v) for v in msg]
    if isinstance(msg, dict):
        return {k: v if type(v) in _SCALARS else to_plain(v) for k, v in msg.items()}
    return msg


@functools.cache
def _field_names(cls: type) -> tuple[str, ...]:
    """The field names of a dataclass, in order (asked once per class: messages are encoded at 250 Hz)."""
    return tuple(fl.name for fl in dataclasses.fields(cls))
