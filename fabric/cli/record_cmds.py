"""CLI commands for records and pictures: ``record`` telemetry to Parquet or CSV, ``plot`` a recording,
``preview`` a G-code file's toolpath."""
from __future__ import annotations

import argparse
import csv
import json
import queue
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

from fabric.cli.output import emit
from fabric.client import Client
from fabric.signals import on_signals
from fabric.wire.errors import BadRequest, FabricError

__all__ = ["register", "sample_row", "write_table", "read_table", "RECORD_TOPICS"]

RECORD_TOPICS = ("pose", "extrusion", "temps", "state", "events")
END_EVENTS = ("finished", "stopped", "fault")
# Every row has these; the other columns are the topic's own (null where a topic has none).
BASE_COLUMNS = ("topic", "rx_seq", "seq", "t_sim_s", "wall_s")


def sample_row(topic: str, msg: Any, rx_seq: int, wall_s: float) -> dict[str, Any]:
    """One flat row of a telemetry message. ``seq`` is the publisher's sequence number where the topic
    has one (pose, extrusion, events: a jump means lost samples), else -1; ``rx_seq`` counts the rows
    of this topic as received."""
    row: dict[str, Any] = {"topic": topic, "rx_seq": rx_seq, "seq": int(getattr(msg, "seq", -1)),
                           "t_sim_s": float(msg.t_sim_s), "wall_s": wall_s}
    if topic == "pose":
        row.update(x_mm=msg.xyz_mm[0], y_mm=msg.xyz_mm[1], z_mm=msg.xyz_mm[2])
        row.update({f"q{i + 1}_deg": float(v) for i, v in enumerate(msg.q_deg)})
    elif topic == "extrusion":
        row.update(on=int(msg.on), flow_mm3_s=msg.flow_mm3_s, flow_r=msg.flow_r, extruded_mm3=msg.extruded_mm3,
                   filament_mm=msg.filament_mm, layer=msg.layer, row=msg.row, gcode_line=msg.gcode_line)
    elif topic == "temps":
        row.update(nozzle_c=msg.nozzle_c, nozzle_target_c=msg.nozzle_target_c, bed_c=msg.bed_c,
                   bed_target_c=msg.bed_target_c)
    elif topic == "state":
        row.update(state=msg.state, reason=msg.reason, progress_r=msg.progress_r, layer=msg.layer,
                   rtf=msg.rtf, speed_r=msg.speed_r, flow_r=msg.flow_r, elapsed_s=msg.elapsed_s,
                   remaining_s=msg.remaining_s, deposited_mm3=msg.deposited_mm3)
    elif topic == "events":
        row.update(kind=msg.kind, layer=msg.layer, row=msg.row, gcode_line=msg.gcode_line,
                   data=json.dumps(msg.data, default=str))
    return row


def _columns(rows: list[dict[str, Any]]) -> list[str]:
    names = list(BASE_COLUMNS)
    for row in rows:
        names += [k for k in row if k not in names]
    return names


def write_table(rows: list[dict[str, Any]], path: Path) -> None:
    """Parquet for ``.parquet``/``.pq``, CSV for ``.csv`` (one column per field; empty where none)."""
    names = _columns(rows)
    suffix = path.suffix.lower()
    if suffix in (".parquet", ".pq"):
        import pyarrow as pa
        import pyarrow.parquet as pq
        table = pa.Table.from_pylist([{n: r.get(n) for n in names} for r in rows]) if rows else \
            pa.table({n: pa.array([], pa.string()) for n in names})
        pq.write_table(table, path)
    elif suffix == ".csv":
        with open(path, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=names)
            w.writeheader()
            w.writerows(rows)
    else:
        raise BadRequest(f"record writes .parquet or .csv, not {path.name!r}", file=str(path))


def read_table(path: Path) -> dict[str, Any]:
    """A recording's columns as numpy arrays (numbers as float, empty cells as NaN)."""
    import numpy as np
    suffix = path.suffix.lower()
    if not path.is_file():
        raise BadRequest(f"no recording at {path}", file=str(path))
    if suffix in (".parquet", ".pq"):
        import pyarrow.parquet as pq
        table = pq.read_table(path)
        cols = {name: table.column(name).to_pylist() for name in table.column_names}
    elif suffix == ".csv":
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
        cols = {name: [r[name] for r in rows] for name in (rows[0].keys() if rows else BASE_COLUMNS)}
    else:
        raise BadRequest(f"plot reads .parquet or .csv, not {path.name!r}", file=str(path))
    out: dict[str, Any] = {}
    for name, values in cols.items():
        if name in ("topic", "state", "reason", "kind", "data"):
            out[name] = np.array(["" if v is None else str(v) for v in values])
        else:
            out[name] = np.array([np.nan if v in (None, "") else float(v) for v in values], dtype=float)
    return out


def gaps(rows: list[dict[str, Any]]) -> dict[str, int]:
    """Samples missing by topic: jumps in the publisher's ``seq`` (topics that number their samples)."""
    last: dict[str, int] = {}
    missing: dict[str, int] = {}
    for r in rows:
        seq = r["seq"]
        if seq < 0:
            continue
        if r["topic"] in last and seq > last[r["topic"]] + 1:
            missing[r["topic"]] = missing.get(r["topic"], 0) + seq - last[r["topic"]] - 1
        last[r["topic"]] = seq
    return missing


def cmd_record(c: Client, a: argparse.Namespace) -> int:
    out = Path(a.output)
    if out.suffix.lower() not in (".parquet", ".pq", ".csv"):
        raise BadRequest(f"record writes .parquet or .csv, not {out.name!r}", file=str(out))
    if out.suffix.lower() != ".csv":
        import pyarrow.parquet  # noqa: F401  (the record extra: missing, say so now, not after the recording)
    topics = list(dict.fromkeys(a.topics))
    inbox: queue.Queue[tuple[str, Any]] = queue.Queue()
    stop = threading.Event()
    subs = {topic: c.subscribe("station", topic) for topic in topics + (["events"] if a.until_end else [])}

    def drain(topic: str) -> None:      # one reader per topic: decode off the Zenoh callback
        while not stop.is_set():
            try:
                inbox.put((topic, subs[topic].get(timeout=0.2)))
            except queue.Empty:
                continue
            except FabricError as err:
                inbox.put((topic, err))
    readers = [threading.Thread(target=drain, args=(t,), daemon=True) for t in subs]
    for r in readers:
        r.start()
    if threading.current_thread() is threading.main_thread():
        on_signals(lambda: stop, (signal.SIGTERM,))
    print(f"recording {' '.join(topics)} to {out} (Ctrl-C stops)", file=sys.stderr, flush=True)
    rows: list[dict[str, Any]] = []
    counts: dict[str, int] = {t: 0 for t in topics}
    bad = 0
    end_event = ""
    deadline = time.monotonic() + a.duration if a.duration else None
    try:
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            try:
                topic, msg = inbox.get(timeout=0.2)
            except queue.Empty:
                continue
            if isinstance(msg, FabricError):
                bad += 1
                continue
            if topic in counts:
                counts[topic] += 1
                rows.append(sample_row(topic, msg, counts[topic], time.time()))
            if a.until_end and topic == "events" and msg.kind in END_EVENTS:
                end_event = msg.kind
                break
    except KeyboardInterrupt:
        pass
    finally:
        stop.set()
        for r in readers:
            r.join(timeout=1.0)
        for sub in subs.values():
            sub.close()
    write_table(rows, out)
    summary = {"path": str(out), "rows": len(rows), "by_topic": counts, "missing_by_topic": gaps(rows),
               "undecodable": bad, "end": end_event}
    emit(summary, a.json, lambda d: (f"wrote {d['path']}: {d['rows']} rows ("
                                     + ", ".join(f"{t} {n}" for t, n in d["by_topic"].items()) + ")"
                                     + (f"; missing by seq: {d['missing_by_topic']}" if d["missing_by_topic"]
                                        else "; no gaps in the sequence numbers")
                                     + (f"; print {d['end']}" if d["end"] else "")))
    return 0


def cmd_plot(a: argparse.Namespace) -> int:
    from fabric.viz import telemetry_png
    path = Path(a.file)
    cols = read_table(path)
    if not len(cols.get("topic", [])):
        raise BadRequest(f"{path} holds no samples", file=str(path))
    Path(a.output).write_bytes(telemetry_png(cols, title=path.name))
    emit({"path": a.output, "rows": int(len(cols["topic"]))}, a.json,
         lambda d: f"wrote {d['path']} ({d['rows']} samples)")
    return 0


def cmd_preview(a: argparse.Namespace) -> int:
    from fabric.gcode import parse_gcode_file
    from fabric.viz import gcode_png
    toolpath = parse_gcode_file(a.file)
    layer = None
    if a.layer is not None:
        if not 1 <= a.layer <= max(toolpath.n_layers, 1):
            raise BadRequest(f"--layer counts from 1 to {toolpath.n_layers}, got {a.layer}", field="layer",
                             value=a.layer, layers=toolpath.n_layers)
        layer = a.layer - 1
    Path(a.output).write_bytes(gcode_png(toolpath, title=Path(a.file).name, layer=layer))
    emit({"path": a.output, "layers": toolpath.n_layers, "moves": len(toolpath)}, a.json,
         lambda d: f"wrote {d['path']} ({d['moves']} moves, {d['layers']} layers)")
    return 0


def register(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser("record", parents=[common], help="record telemetry to Parquet or CSV (by the file's extension)")
    p.add_argument("topics", nargs="+", choices=RECORD_TOPICS, metavar="TOPIC",
                   help=f"what to record: {', '.join(RECORD_TOPICS)}")
    p.add_argument("-o", "--output", required=True, help="FILE.parquet or FILE.csv")
    p.add_argument("--duration", type=float, default=0.0, metavar="S", help="stop after S seconds (0: Ctrl-C)")
    p.add_argument("--until-end", action="store_true", help="stop when a print finishes, stops or faults")
    p.set_defaults(run=cmd_record)
    p = sub.add_parser("plot", parents=[common], help="plot a recording: temperatures, speed, flow, extrusion")
    p.add_argument("file")
    p.add_argument("-o", "--output", required=True, help="PNG file")
    p.set_defaults(local=cmd_plot)
    p = sub.add_parser("preview", parents=[common], help="draw a G-code file's toolpath as a PNG")
    p.add_argument("file")
    p.add_argument("-o", "--output", required=True, help="PNG file")
    p.add_argument("--layer", type=int, default=None, metavar="N", help="the part up to layer N, and layer N alone")
    p.set_defaults(local=cmd_preview)
