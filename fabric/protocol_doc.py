"""Generates the protocol reference from the code, so it cannot drift: docs/protocol.md and docs/protocol.json.

    python -m fabric.protocol_doc > docs/protocol.md
    python -m fabric.protocol_doc --json > docs/protocol.json

Sources: the key and endpoint table (``fabric.wire.keys``), the schemas and their
comments (``fabric.schemas``, read by ``fabric.reference.fields``), the QoS
(``fabric.wire.qos``), the errors (``fabric.wire.errors``), the rates the services
publish at, and ``fabric.reference`` (events, prose, examples). Tests fail when
either file is stale or a description is cut short.
"""
from __future__ import annotations

import argparse
import base64
import dataclasses
import inspect
import json
import re
import sys
import textwrap
import types
import typing
from typing import Any, Union

import numpy as np

from fabric import schemas as s
from fabric.reference import examples, prose
from fabric.reference.errors import ERROR_DETAILS
from fabric.reference.events import EVENTS, JOB_DATA
from fabric.reference.fields import field_docs, member_docs, message_doc
from fabric.reference.machine import describe, event_data_schema, message_schemas, to_json_value
from fabric.schemas import REGISTRY, states
from fabric.schemas.upload import MIB
from fabric.wire import codec, errors, qos
from fabric.wire.keys import ARTIFACT_SOURCES, ARTIFACT_TIMEOUT_S, CELL_PATTERN, ENDPOINTS, SERVICES, TOPICS

__all__ = ["render", "render_json", "description", "facts", "inputs", "LOSSLESS"]

LOSSLESS = {("station", "state"), ("station", "events"), ("slicer", "progress"), ("planner", "progress"),
            ("supervisor", "jobs"), ("supervisor", "queue")}
"""The topics published with congestion control BLOCK (every other is DROP); the contract test checks them."""


def facts() -> dict[str, Any]:
    """The values the reference states, read from the code that sets them."""
    from fabric.client.client import DISCOVERY_WINDOW_S
    from fabric.printjobs.queue import STATION_FREE
    from fabric.security.roles import MONITOR_COMMANDS
    from fabric.server.jobs import PROGRESS_PERIOD_S
    from fabric.server.uploads import UploadStore
    from fabric.services.station import STATE_PERIOD_S, StationService
    from fabric.services.station_messages import JOB_EVENTS
    from fabric.services.telemetry_gate import EXTRUSION_PERIOD_S, TEMPS_PERIOD_S
    from fabric.sim.types import EVENT_KINDS
    from fabric.store.station import StationStore
    from fabric.wire.config import SessionSettings
    pose_hz = inspect.signature(StationService.__init__).parameters["pose_hz"].default
    keep_events = inspect.signature(StationStore.__init__).parameters["keep_events"].default
    uploads_kept = inspect.signature(UploadStore.__init__).parameters["max_open"].default
    settings = {f.name: f.default for f in dataclasses.fields(SessionSettings)}
    query = {f.name: f.default for f in dataclasses.fields(s.JobsQuery)}
    return {"pose_hz": float(pose_hz), "state_period_s": STATE_PERIOD_S, "extrusion_period_s": EXTRUSION_PERIOD_S,
            "temps_period_s": TEMPS_PERIOD_S, "progress_period_s": PROGRESS_PERIOD_S,
            "job_events": tuple(JOB_EVENTS), "event_kinds": tuple(EVENT_KINDS), "keep_events": int(keep_events),
            "default_cell": settings["cell"], "cell_pattern": CELL_PATTERN, "station_free": STATION_FREE,
            "monitor_commands": sorted(f"{svc}/{cmd}" for svc, cmd in MONITOR_COMMANDS),
            "discovery_s": DISCOVERY_WINDOW_S, "jobs_limit": query["limit"], "jobs_max": s.MAX_JOBS_PAGE,
            "uploads_kept": int(uploads_kept)}


def inputs() -> list[dict[str, Any]]:
    """Every request that carries a file (a ``bin`` field with a largest size), the field, the upload endpoint
    that may carry it instead ("" when none) and the most bytes it takes."""
    rows = []
    for (svc, cmd), ep in ENDPOINTS.items():
        if cmd == "upload":                       # the pieces themselves
            continue
        docs = field_docs(ep.request)
        named = (svc, "upload") in ENDPOINTS and any(fd.name == "upload_id" for fd in docs)
        upload = f"{svc}/upload" if named else ""
        for fd in docs:
            if fd.tp is bytes and fd.spec.max_len is not None:
                rows.append({"command": f"{svc}/{cmd}", "request": ep.request.TYPE, "field": fd.name,
                             "upload": upload, "max_bytes": fd.spec.max_len})
    return rows


def _mib(n_bytes: int) -> str:
    """A size in MiB, as the reference writes it (``512``)."""
    return f"{n_bytes / MIB:g}"


# --- what each part says ---------------------------------------------------------------------------------------

def _qos_of(bulk: bool) -> dict[str, Any]:
    """An endpoint's QoS as plain names (from ``fabric.wire.qos``)."""
    kw = qos.BULK_QOS if bulk else qos.INTERACTIVE_QOS
    priority = kw.get("priority")
    consolidation = kw.get("consolidation")
    return {"priority": _name(priority) if priority is not None else "DATA",
            "express": bool(kw.get("express", False)),
            "consolidation": _name(consolidation) if consolidation is not None else "DEFAULT"}


def _name(value: Any) -> str:
    """A Zenoh enum member's name (``Priority.INTERACTIVE_HIGH`` -> ``INTERACTIVE_HIGH``)."""
    return str(value).rsplit(".", 1)[-1]


def _topic_when(svc: str, topic: str, f: dict[str, Any]) -> str:
    period_ms = 1000.0 / f["pose_hz"]
    return {
        ("station", "pose"): f"a sample every {period_ms:g} ms of wall clock ({f['pose_hz']:g} Hz by default, "
                             f"`--pose-hz`)",
        ("station", "extrusion"): f"on each switch of the extruder and change of flow, layer or flow override, "
                                  f"else every {f['extrusion_period_s']:g} s (asked at each pose sample); its own "
                                  f"gap-free `seq`",
        ("station", "temps"): f"on a new set point, else every {f['temps_period_s']:g} s (asked at each pose "
                              f"sample)",
        ("station", "state"): f"on every change of state, reason, program, plate, layer, rtf, overrides or "
                              f"progress (0.1 %), and every {f['state_period_s']:g} s",
        ("station", "events"): "each event as it happens, in order (several per tick at a high rtf)",
        ("station", "deviation"): "with each pose sample while the station drives a robot (`--robot`); never for "
                                  "the twin alone",
        ("slicer", "progress"): f"on every change of a job's state or stage, else every {f['progress_period_s']:g} s "
                                f"while it runs",
        ("planner", "progress"): f"on every change of a job's state or stage, else every "
                                 f"{f['progress_period_s']:g} s while it runs",
        ("supervisor", "jobs"): "the whole record of a print job on every change of it",
        ("supervisor", "queue"): "when a job is submitted, removed or moved in the queue (a removal has no record "
                                 "to publish on `jobs`)",
    }[(svc, topic)]


def _time_base(description: str) -> str:
    """Which clock a ``*_s`` field's description says it is on ("" when it says none: a test fails then)."""
    text = description.lower()
    if "wall" in text and any(w in text for w in ("took", "duration", "how long")):
        return "wall-clock duration"
    if "epoch" in text or "wall" in text:
        return "wall clock, epoch seconds"
    if "simulat" in text or "clock" in text:
        return "simulated"
    return ""


def _time_fields() -> list[tuple[str, str, str]]:
    """(message.field, time base, description) of every ``*_s`` field that is a time (not a speed)."""
    rows = []
    for name, cls in sorted(REGISTRY.items()):
        for fd in field_docs(cls):
            if fd.unit == "seconds":
                rows.append((f"{name}.{fd.name}", _time_base(fd.description), fd.description))
    return rows


# --- Markdown ------------------------------------------------------------------------------------------------

def _fill(text: str, values: dict[str, Any]) -> str:
    def sub(m: re.Match[str]) -> str:
        if m.group(1) not in values:
            raise KeyError(f"the reference's prose names @@{m.group(1)}@@, which no value fills")
        return str(values[m.group(1)])
    return re.sub(r"@@(\w+)@@", sub, text)


def _cell(text: str) -> str:
    """Text for one Markdown table cell."""
    return text.replace("|", "\\|").replace("\n", " ")


def _type_name(tp: Any, spec: Any = None) -> str:
    origin = typing.get_origin(tp)
    if origin in (Union, types.UnionType):
        inner = [a for a in typing.get_args(tp) if a is not type(None)]
        return _type_name(inner[0], spec) + " or nil"
    if tp is np.ndarray:
        extra = []
        if spec is not None and spec.dtype:
            extra.append(np.dtype(spec.dtype).str)
        if spec is not None and spec.shape:
            extra.append("shape " + "x".join("n" if d is None else str(d) for d in spec.shape))
        return "packed array" + (f" ({', '.join(extra)})" if extra else "")
    if origin is list:
        n = spec.shape[0] if spec is not None and spec.shape and len(spec.shape) == 1 else None
        return f"array of {'' if n is None else str(n) + ' '}{_type_name(typing.get_args(tp)[0])}"
    if origin is dict:
        return f"map str -> {_type_name(typing.get_args(tp)[1])}"
    if hasattr(tp, "TYPE"):
        return f"[`{tp.TYPE}`](#{_anchor(tp.TYPE)})"
    return {float: "float", int: "int", str: "str", bool: "bool", bytes: "bin", Any: "any"}.get(tp, str(tp))


def _anchor(type_name: str) -> str:
    """The Markdown anchor of a message's heading (``### `station.Pose` (v1)`` -> ``stationpose-v1``)."""
    cls = REGISTRY[type_name]
    heading = f"{type_name} (v{cls.VERSION})"
    return re.sub(r"[^a-z0-9 _-]", "", heading.lower()).replace(" ", "-")


def _constraints(fd: Any) -> str:
    spec = fd.spec
    parts = []
    if spec.ge is not None:
        parts.append(f">= {spec.ge:g}")
    if spec.le is not None:
        parts.append(f"<= {spec.le:g}")
    if spec.choices is not None:
        parts.append("one of " + ", ".join(f"`{c}`" if c != "" else '`""`' for c in spec.choices))
    if spec.min_len is not None:
        parts.append(f"at least {spec.min_len} chars")
    if spec.max_len is not None:
        parts.append(f"at most {_mib(spec.max_len)} MiB" if fd.tp is bytes else f"at most {spec.max_len} chars")
    if spec.pattern is not None:
        parts.append(f"matches `{spec.pattern}` whole")
    if fd.default is dataclasses.MISSING:
        parts.append("**required**")
    else:
        parts.append(f"default `{_json(to_json_value(fd.default), readable=True)}`")
    return "; ".join(parts)


def _readable(value: Any) -> Any:
    """A plain message value with bins as ``"bin:<text>"`` (the Markdown examples' convention)."""
    if isinstance(value, dict):
        return {k: _readable(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_readable(v) for v in value]
    if isinstance(value, bytes):
        return "bin:" + value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray):
        return {"nd": True, "dtype": value.dtype.str, "shape": list(value.shape), "data": f"bin:<{value.nbytes} bytes>"}
    return value


def _json(value: Any, readable: bool = False) -> str:
    return json.dumps(value, ensure_ascii=False, separators=(", ", ": "))


def _wire(msg: Any) -> dict[str, Any]:
    """A message as the wire carries it (tags first), decoded back: what the examples show."""
    return typing.cast(dict[str, Any], codec.unpack(codec.encode(msg)))


def _example_json(msg: Any) -> str:
    """A message as msgpack-as-JSON, one top-level field a line."""
    body = _readable(_wire(msg))
    lines = [f"  {json.dumps(k)}: {_json(v)}" for k, v in body.items()]
    return "{\n" + ",\n".join(lines) + "\n}"


def _commands_table() -> list[str]:
    rows = []
    for (svc, cmd), ep in ENDPOINTS.items():
        q = _qos_of(ep.bulk)
        how = f"{q['priority']}{', express' if q['express'] else ''}" + (", bulk" if ep.bulk else "")
        rows.append(f"| `am/<cell>/{svc}/cmd/{cmd}` | [`{ep.request.TYPE}`](#{_anchor(ep.request.TYPE)}) | "
                    f"[`{ep.reply.TYPE}`](#{_anchor(ep.reply.TYPE)}) | {ep.timeout_s:g} s | {how} | {_cell(ep.doc)} |")
    for svc, src in ARTIFACT_SOURCES.items():
        q = _qos_of(src.bulk)
        how = f"{q['priority']}{', express' if q['express'] else ''}" + (", bulk" if src.bulk else "")
        reply = src.reply.TYPE
        rows.append(f"| `am/<cell>/{svc}/artifact/<id>` | no payload | [`{reply}`](#{_anchor(reply)}) | "
                    f"{src.timeout_s:g} s | {how} | {_cell(src.doc)} |")
    return rows


def _state_rows(enum: Any) -> str:
    """The Markdown rows of a state table: each state and its meaning (its comment in fabric.schemas.states)."""
    return "\n".join(f"| `{value}` | {_cell(text)} |" for value, text in member_docs(enum).items())


def _events_rows(f: dict[str, Any]) -> list[str]:
    rows = []
    for kind in f["event_kinds"]:
        entry = EVENTS[kind]
        data = dict(entry.data)
        keys = [f"`{k}` ({t}{', optional' if k in entry.optional else ''}): {d}" for k, (t, d) in data.items()]
        if kind in f["job_events"]:
            keys += [f"`{k}` ({t}, a job's): {d}" for k, (t, d) in JOB_DATA.items() if k not in data]
        rows.append(f"| `{kind}` | {_cell(entry.when)} | {'<br>'.join(_cell(k) for k in keys) or 'nothing'} |")
    return rows


def _messages() -> list[str]:
    out = ["## Messages\n", "Every message type, its current version and every field: type, unit (from the name), "
           "range and choices, default (a field without one is required), and what it means.\n"]
    for name, cls in sorted(REGISTRY.items()):
        out.append(f"### `{name}` (v{cls.VERSION})\n")
        doc = message_doc(cls)
        if doc:
            out.append(doc + "\n")
        docs = field_docs(cls)
        if not docs:
            out.append("No fields.\n")
            continue
        out.append("| field | type | unit | constraints | meaning |\n|---|---|---|---|---|")
        for fd in docs:
            out.append(f"| `{fd.name}` | {_type_name(fd.tp, fd.spec)} | {fd.unit} | {_cell(_constraints(fd))} | "
                       f"{_cell(fd.description)} |")
        out.append("")
    return out


def _examples_md() -> list[str]:
    out = ["## Worked examples\n",
           "One per command: the request sent as the query's payload and the reply, as msgpack shown as JSON "
           "(a `bin` is `\"bin:...\"`; see [Payloads](#payloads)). Every example is built from the schemas "
           "and checked against docs/protocol.json by the tests.\n"]
    for (svc, cmd), (req, rep) in examples.COMMAND_EXAMPLES.items():
        out.append(f"### `{svc}/{cmd}`\n")
        out.append(f"{ENDPOINTS[(svc, cmd)].doc[:1].upper()}{ENDPOINTS[(svc, cmd)].doc[1:]}: query "
                   f"`am/cell1/{svc}/cmd/{cmd}` with\n")
        out.append("```json\n" + _example_json(req) + "\n```\n")
        out.append("and get\n")
        out.append("```json\n" + _example_json(rep) + "\n```\n")
    out.append("### Publications\n")
    for (svc, topic), msg in examples.TOPIC_EXAMPLES.items():
        out.append(f"`am/cell1/{svc}/{topic}`:\n")
        out.append("```json\n" + _example_json(msg) + "\n```\n")
    return out


def render() -> str:
    """docs/protocol.md."""
    f = facts()
    values: dict[str, Any] = {
        "default_cell": f["default_cell"], "cell_pattern": f["cell_pattern"],
        "monitor_commands": ", ".join(f"`{c}`" for c in f["monitor_commands"]),
        "services": ", ".join(f"`{svc}`" for svc in SERVICES),
        "dtypes": ", ".join(f"`{d}`" for d in sorted(codec.PACKED_DTYPES)),
        "empty_len": len(codec.encode(s.Empty())), "empty_hex": codec.encode(s.Empty()).hex(" "),
        "cmd_priority": _qos_of(False)["priority"], "bulk_priority": _qos_of(True)["priority"],
        "discovery_s": f"{f['discovery_s']:g}",
        "error_tree": textwrap.dedent((errors.__doc__ or "").split("::\n", 1)[1].split("\n\nEvery error")[0]).strip(),
        "error_details": "\n".join(f"| `{code}` | {_fill(_cell(text), _error_values())} |"
                                   for code, text in ERROR_DETAILS.items()),
        "topic_rows": "\n".join(
            f"| `am/<cell>/{svc}/{topic}` | [`{tp.TYPE}`](#{_anchor(tp.TYPE)}) | "
            f"{'lossless (BLOCK)' if (svc, topic) in LOSSLESS else 'sampled (DROP)'} | {_topic_when(svc, topic, f)} |"
            for (svc, topic), tp in TOPICS.items()),
        "pose_period_ms": f"{1000.0 / f['pose_hz']:g}",
        "time_rows": "\n".join(f"| `{field}` | {base} |" for field, base, _ in _time_fields()),
        "keep_events": f"{f['keep_events']:,}",
        "job_events": ", ".join(f"`{k}`" for k in f["job_events"]),
        "event_rows": "\n".join(_events_rows(f)),
        "gcode_suffixes": ", ".join(f"`{x}`" for x in s.pipeline.GCODE_SUFFIXES),
        "model_suffixes": ", ".join(f"`{x}`" for x in s.pipeline.MODEL_SUFFIXES),
        "station_free": ", ".join(f"`{x}`" for x in f["station_free"]),
        "jobs_limit": f["jobs_limit"], "jobs_max": f"{f['jobs_max']:,}",
        "progress_period_s": f"{f['progress_period_s']:g}",
        "chunk_max_mib": _mib(s.upload.UPLOAD_CHUNK_MAX_BYTES), "chunk_mib": _mib(s.upload.UPLOAD_CHUNK_BYTES),
        "inline_mib": _mib(s.upload.INLINE_MAX_BYTES), "uploads_kept": f["uploads_kept"],
        "model_mib": _mib(s.upload.MAX_MODEL_BYTES), "gcode_mib": _mib(s.upload.MAX_GCODE_BYTES),
        "input_rows": "\n".join(
            f"| `{i['command']}` ([`{i['request']}`](#{_anchor(i['request'])})) | `{i['field']}` | "
            f"{f'`{u}`' if (u := i['upload']) else 'inline only'} | {_mib(i['max_bytes'])} MiB |" for i in inputs()),
        "print_job_state_rows": _state_rows(states.PrintJob), "job_state_rows": _state_rows(states.Job),
        "artifact_timeout_s": f"{ARTIFACT_TIMEOUT_S:g}",
        "artifact_rows": "\n".join(f"| `{svc}` | {', '.join(f'`{m}`' for m in src.media_types)} | {_cell(src.doc)} |"
                                   for svc, src in ARTIFACT_SOURCES.items()),
    }
    head = ["# am-fabric wire protocol\n",
            "Generated by `python -m fabric.protocol_doc > docs/protocol.md` from the code (`fabric/wire/keys.py`, "
            "`fabric/schemas/`, `fabric/reference/`); the same facts for machines, with a JSON Schema per message, "
            "are in [protocol.json](protocol.json) (`--json`). Tests fail when either is stale.\n",
            "Contents: [Transport](#transport-and-defaults), [Keys](#keys), [Payloads](#payloads), "
            "[Versions](#versions-_v), [Commands](#commands), [Errors](#errors), [Inputs](#inputs), "
            "[Telemetry](#telemetry), "
            "[Time bases](#time-bases), [Station states](#station-states), [Events](#events), "
            "[Print jobs](#print-jobs), [Slicing and planning jobs](#slicing-and-planning-jobs), "
            "[Multi-axis G-code](#multi-axis-g-code-curved-layers), "
            "[Artifacts](#artifacts), [A plain client](#a-client-with-nothing-but-zenoh-and-msgpack), "
            "[Worked examples](#worked-examples), [Messages](#messages).\n"]
    out = head
    for key in ("transport", "keys", "payloads", "versions"):
        out.append(_fill(prose.SECTIONS[key], values))
    out.append(_fill(prose.SECTIONS["commands"], values).rstrip("\n"))
    out += _commands_table()
    out.append("")
    for key in ("errors", "inputs", "telemetry", "time_bases", "station_states", "events", "print_jobs",
                "pipeline_jobs", "multiaxis", "artifacts", "plain_client"):
        out.append(_fill(prose.SECTIONS[key], values))
    out += _examples_md()
    out += _messages()
    return "\n".join(out).rstrip("\n") + "\n"


def _error_values() -> dict[str, str]:
    return {"unreachable": ", ".join(f"`{r}`" for r in errors.UNREACHABLE_REASONS),
            "cold": ", ".join(f"`{r}`" for r in errors.COLD_EXTRUSION_REASONS),
            "decode_reasons": ", ".join(f"`{r}`" for r in codec.DECODE_REASONS)}


# --- JSON ----------------------------------------------------------------------------------------------------

def description() -> dict[str, Any]:
    """docs/protocol.json as a dict."""
    f = facts()
    endpoints = []
    for (svc, cmd), ep in ENDPOINTS.items():
        req, rep = examples.COMMAND_EXAMPLES[(svc, cmd)]
        endpoints.append({"service": svc, "command": cmd, "key": f"am/{{cell}}/{svc}/cmd/{cmd}",
                          "request": ep.request.TYPE, "reply": ep.reply.TYPE, "timeout_s": ep.timeout_s,
                          "bulk": ep.bulk, "qos": _qos_of(ep.bulk), "doc": ep.doc,
                          "example": {"request": to_json_value(_wire(req)), "reply": to_json_value(_wire(rep))}})
    topics = [{"service": svc, "topic": topic, "key": f"am/{{cell}}/{svc}/{topic}", "payload": tp.TYPE,
               "reliability": "RELIABLE", "priority": "DATA",
               "congestion_control": "BLOCK" if (svc, topic) in LOSSLESS else "DROP",
               "when": _topic_when(svc, topic, f),
               "example": to_json_value(_wire(examples.TOPIC_EXAMPLES[(svc, topic)]))}
              for (svc, topic), tp in TOPICS.items()]
    error_codes = {code: {"class": cls.__name__, "parent": _parent_code(cls),
                          "details": _fill(ERROR_DETAILS[code], _error_values()).replace("`", "")}
                   for code, cls in errors.ERROR_CLASSES.items()}
    events = {kind: {"when": EVENTS[kind].when, "job_event": kind in f["job_events"],
                     "data": event_data_schema(kind, f["job_events"])} for kind in f["event_kinds"]}
    return describe({
        "defaults": {"cell": f["default_cell"], "hub": "tcp/127.0.0.1:7447", "cell_pattern": f["cell_pattern"]},
        "services": list(SERVICES),
        "keys": {"alive": "am/{cell}/alive/{service}", "alive_every_cell": "am/*/alive/*",
                 "command": "am/{cell}/{service}/cmd/{command}", "unknown_command": "am/{cell}/{service}/cmd/**",
                 "artifact": "am/{cell}/{service}/artifact/{artifact_id}", "topic": "am/{cell}/{service}/{topic}",
                 "health_every_service": "am/{cell}/*/cmd/health"},
        "encoding": {"format": "msgpack", "tags": {"_t": "message type", "_v": "schema version"},
                     "empty_request": base64.b64encode(codec.encode(s.Empty())).decode(),
                     "bin": "base64 text in this document", "packed_array_dtypes": sorted(codec.PACKED_DTYPES),
                     "versioning": "A receiver takes versions 1 to its own of a type (missing fields take their "
                                   "defaults) and refuses a newer one with a decode error (reason version), "
                                   "whatever the type: common.Empty too, also where it stands for a request whose "
                                   "fields all have defaults.",
                     "sizes": "Sizes are in bytes; where this description gives one in MiB, 1 MiB = 1048576 bytes "
                              "(a name ending _mb counts MiB too).",
                     "decode_reasons": list(codec.DECODE_REASONS)},
        "rates": {"pose_hz": f["pose_hz"], "state_period_s": f["state_period_s"],
                  "extrusion_period_s": f["extrusion_period_s"], "temps_period_s": f["temps_period_s"],
                  "progress_period_s": f["progress_period_s"]},
        "endpoints": endpoints,
        "artifact_queries": [{"service": svc, "key": f"am/{{cell}}/{svc}/artifact/{{artifact_id}}", "request": None,
                              "reply": src.reply.TYPE, "timeout_s": src.timeout_s, "bulk": src.bulk,
                              "qos": _qos_of(src.bulk), "media_types": list(src.media_types), "doc": src.doc}
                             for svc, src in ARTIFACT_SOURCES.items()],
        "inputs": inputs(),
        "topics": topics,
        "artifacts": {svc: list(src.media_types) for svc, src in ARTIFACT_SOURCES.items()},
        "errors": error_codes,
        "events": events,
        "$defs": message_schemas(REGISTRY, sorted(codec.PACKED_DTYPES)),
    })


def _parent_code(cls: type[errors.FabricError]) -> str:
    """The code of the error class ``cls`` derives from, below FabricError ("" for the first level)."""
    parent = cls.__mro__[1]
    if cls is errors.FabricError or parent is errors.FabricError or not issubclass(parent, errors.FabricError):
        return ""
    return parent.code


def render_json() -> str:
    """docs/protocol.json."""
    return json.dumps(description(), indent=1, ensure_ascii=False) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m fabric.protocol_doc", description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="the machine-readable description (docs/protocol.json)")
    args = parser.parse_args(argv)
    sys.stdout.write(render_json() if args.json else render())
    return 0


if __name__ == "__main__":
    sys.exit(main())
