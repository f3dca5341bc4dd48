"""CLI commands for the supervisor's file library: list, show, add, get, remove, and print a file again."""
from __future__ import annotations

import argparse
from pathlib import Path

from fabric import schemas as s
from fabric.cli.inputs import read_whole
from fabric.cli.job_cmds import add_follow_args, submit_and_follow
from fabric.cli.output import emit
from fabric.cli.pipeline_cmds import parse_sets
from fabric.client import Client
from fabric.printjobs.library_text import date_text, plan_text, size_text

__all__ = ["register"]


def _list_text(page: s.FileList) -> str:
    if not page.files:
        return "the library is empty (files enter it when submitted, or with fabric-cli files add)" \
            if page.total == 0 else f"no files from {page.offset + 1} (of {page.total})"
    head = f"{'file':<12}  {'name':<28} {'kind':<6} {'size':>9}  {'last used':<16}  {'jobs':>4}  last job"
    rows = [f"{e.file_id}  {e.name[:28]:<28} {e.source:<6} {size_text(e.size_bytes):>9}  "
            f"{date_text(e.used_s or e.added_s):<16}  {e.jobs:>4}  {(e.last_state or '-'):<10} {plan_text(e)}"
            for e in page.files]
    if len(page.files) < page.total:
        rows.append(f"showing {page.offset + 1}-{page.offset + len(page.files)} of {page.total}")
    return "\n".join([head, *rows])


def _entry_text(e: s.LibraryFile) -> str:
    lines = [f"file {e.file_id}: {e.name} ({e.source}, {size_text(e.size_bytes)})",
             f"  added      {date_text(e.added_s)}   last used {date_text(e.used_s)}   jobs {e.jobs}",
             f"  last job   {e.last_job_id or '-'} {e.last_state}",
             f"  plan       {plan_text(e)}",
             f"  settings   profile {e.profile}, slicer {e.backend}, rtf {e.rtf:g}"
             + (f", filament {e.filament_diameter_mm:g} mm" if e.filament_diameter_mm else "")
             + "".join(f", {k}={v}" for k, v in sorted(e.overrides.items()))]
    return "\n".join(lines)


def cmd_print(c: Client, a: argparse.Namespace) -> int:
    """Print a library file again: the settings of its last job, unless given here."""
    e = c.file(a.file_id)
    overrides = parse_sets(a.set) if a.set else dict(e.overrides)
    req = s.JobSubmit(model=b"", filename="", file_id=e.file_id,
                      profile=a.profile or e.profile, backend=a.backend or e.backend,
                      overrides=overrides if e.source == "model" else {},
                      start=a.start, rtf=e.rtf if a.rtf is None else a.rtf,
                      filament_diameter_mm=a.filament_diameter or e.filament_diameter_mm,
                      layers=(a.layers or e.layer_mode) if e.source == "model" else "planar")
    return submit_and_follow(c, a, req)


def cmd_get(c: Client, a: argparse.Namespace) -> int:
    e = c.file(a.file_id)
    art = c.artifact("supervisor", e.content_id, timeout=120.0)
    out = Path(a.output or e.name)
    out.write_bytes(art.data)
    emit({"path": str(out), "bytes": len(art.data), "file_id": e.file_id}, a.json,
         lambda d: f"wrote {d['path']} ({d['bytes']} bytes)")
    return 0


def register(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    files = sub.add_parser("files", help="the file library: every submitted model and G-code file, to print again")
    fsub = files.add_subparsers(dest="files_cmd", required=True)
    p = fsub.add_parser("list", parents=[common], help="the library, most recently used first")
    p.add_argument("--name", default="", help="only files whose name contains this (any case)")
    p.add_argument("--offset", type=int, default=0)
    p.add_argument("--limit", type=int, default=100, help=f"show at most this many (up to {s.MAX_FILES_PAGE})")
    p.set_defaults(run=lambda c, a: _shown(c.files(a.offset, a.limit, a.name), a, _list_text))
    p = fsub.add_parser("show", parents=[common], help="one library file: what it is, its last job and settings")
    p.add_argument("file_id", help="the file's id, or a unique start of it (6 characters or more)")
    p.set_defaults(run=lambda c, a: _shown(c.file(a.file_id), a, _entry_text))
    p = fsub.add_parser("add", parents=[common], help="keep a model or G-code file in the library (not printed)")
    p.add_argument("file")
    p.add_argument("--source", choices=s.pipeline.JOB_SOURCES, default=None,
                   help="model or gcode (default: from the file name)")
    p.set_defaults(run=lambda c, a: _shown(c.file_add(read_whole(a.file), Path(a.file).name, a.source or ""), a,
                                           lambda e: f"kept {e.name} as file {e.file_id}"))
    p = fsub.add_parser("get", parents=[common], help="write a library file's bytes to disk")
    p.add_argument("file_id")
    p.add_argument("-o", "--output", default=None, help="where (default: its name, here)")
    p.set_defaults(run=cmd_get)
    p = fsub.add_parser("remove", aliases=["rm"], parents=[common], help="forget a library file")
    p.add_argument("file_id")
    p.set_defaults(run=lambda c, a: _shown(c.file_remove(a.file_id), a, lambda r: r.message))
    p = fsub.add_parser("print", parents=[common],
                        help="print a library file again (its last job's settings unless given)")
    p.add_argument("file_id")
    p.add_argument("--profile", default=None)
    p.add_argument("--backend", default=None, choices=s.pipeline.BACKENDS)
    p.add_argument("--layers", default=None, choices=s.pipeline.LAYER_MODES,
                   help="planar or curved layers (default: the last job's)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a profile key (replaces the last "
                   "job's overrides)")
    p.add_argument("--filament-diameter", type=float, default=None, metavar="MM")
    p.add_argument("--start", action="store_true", help="start printing once loaded (when the plate is clear)")
    p.add_argument("--rtf", type=float, default=None, help="real-time factor (default: the last job's)")
    add_follow_args(p)
    p.set_defaults(run=cmd_print)


def _shown(reply: object, a: argparse.Namespace, text) -> int:
    emit(reply, a.json, text)
    return 0
