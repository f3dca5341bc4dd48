"""What the reference says of each message and field: read from the schema classes and their source comments.

A field's description is its comments in the schema's source: comment lines right
above it (at its indentation), the comment at the end of its line, and comment
lines right below it indented further (a continuation); a state's meaning (a
member of an enum of ``fabric.schemas.states``) is read the same way. A
message's description is its whole docstring. Units come from the field name's
suffix (house rule: names carry units), defaults and ranges from the field's
declaration.
"""
from __future__ import annotations

import ast
import dataclasses
import inspect
import io
import textwrap
import tokenize
from dataclasses import dataclass
from enum import Enum
from functools import cache
from typing import Any

import numpy as np

__all__ = ["FieldDoc", "message_doc", "field_docs", "unit_of", "UNITS", "default_of", "json_default", "member_docs"]

# name suffix -> unit, longest first where one suffix ends another
UNITS: tuple[tuple[str, str], ...] = (
    ("_mm3_mm", "mm³ per mm of path"), ("_mm3_s", "mm³/s"), ("_mm_s", "mm/s"), ("_g_cm3", "g/cm³"),
    ("_mm3", "mm³"), ("_mm", "mm"), ("_deg", "degrees"), ("_rad", "radians"), ("_s", "seconds"),
    ("_c", "°C"), ("_r", "ratio (1 = 100 %)"), ("_g", "grams"), ("_bytes", "bytes"), ("_hz", "Hz"),
)


@dataclass(frozen=True)
class FieldDoc:
    """One field as the reference shows it."""
    name: str
    tp: Any                       # the annotation (resolved)
    spec: Any                     # the schema's FieldSpec (range, choices, dtype, shape, length, required)
    description: str              # from the source comments ("" when there are none)
    unit: str                     # from the name's suffix ("" when it has none)
    default: Any                  # the default value (dataclasses.MISSING when required)


def unit_of(name: str) -> str:
    """The unit a field's name carries (``t_sim_s`` -> seconds), or ""."""
    for suffix, unit in UNITS:
        if name.endswith(suffix):
            return unit
    return ""


def message_doc(cls: type) -> str:
    """A message's whole docstring, paragraphs kept ("" when it has none of its own)."""
    doc = cls.__doc__ or ""
    if not doc.strip() or doc.startswith(cls.__name__ + "("):      # dataclass's generated signature
        return ""
    return inspect.cleandoc(doc)


def default_of(cls: type, name: str) -> Any:
    """The default of field ``name`` (``dataclasses.MISSING`` when it is required)."""
    fld = next(fl for fl in dataclasses.fields(cls) if fl.name == name)
    if fld.default is not dataclasses.MISSING:
        return fld.default
    if fld.default_factory is not dataclasses.MISSING:
        return fld.default_factory()
    return dataclasses.MISSING


def json_default(value: Any) -> Any:
    """A default as JSON shows it (``bin`` as base64 text, packed arrays as nested lists)."""
    import base64
    if isinstance(value, bytes):
        return base64.b64encode(value).decode()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value


def field_docs(cls: type) -> list[FieldDoc]:
    """Every field of schema ``cls``, in declaration order."""
    comments = _comments(cls)
    # the type as the wire carries it (a state field's enum is a str with its values as choices)
    return [FieldDoc(name, spec.tp, spec, comments.get(name, ""), unit_of(name), default_of(cls, name))
            for name, spec in cls.SPECS.items()]  # type: ignore[attr-defined]


def member_docs(states: type[Enum]) -> dict[str, str]:
    """Every member of the enum ``states`` (its value) -> its meaning (its comments; "" when it has none)."""
    comments = _comments(states)
    return {str(member.value): comments.get(member.name, "") for member in states}


@cache
def _comments(cls: type) -> dict[str, str]:
    """Field name -> the text of its comments in the class's source (see the module docstring)."""
    source = textwrap.dedent(inspect.getsource(cls))
    lines = source.splitlines()
    by_line: dict[int, tuple[int, str, bool]] = {}          # line -> (column, text, alone on its line)
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            row, col = tok.start
            alone = not lines[row - 1][:col].strip()
            by_line[row] = (col, tok.string.lstrip("#").strip(), alone)
    body = next(n for n in ast.parse(source).body if isinstance(n, ast.ClassDef)).body
    fields = [(n.target.id, n.lineno, n.end_lineno or n.lineno, n.col_offset) for n in body
              if isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name)]
    fields += [(n.targets[0].id, n.lineno, n.end_lineno or n.lineno, n.col_offset) for n in body   # enum members
               if isinstance(n, ast.Assign) and len(n.targets) == 1 and isinstance(n.targets[0], ast.Name)]
    out = {}
    for name, first, last, col in fields:
        parts: list[str] = []
        above = first - 1                        # own-line comments right above, at the field's indentation
        lead: list[str] = []
        while above in by_line and by_line[above][2] and by_line[above][0] == col:
            lead.insert(0, by_line[above][1])
            above -= 1
        parts += lead
        parts += [by_line[r][1] for r in range(first, last + 1) if r in by_line and not by_line[r][2]]
        below = last + 1                         # continuation lines: own-line comments indented further
        while below in by_line and by_line[below][2] and by_line[below][0] > col:
            parts.append(by_line[below][1])
            below += 1
        out[name] = " ".join(p for p in parts if p)
    return out
