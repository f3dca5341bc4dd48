"""CLI commands for print jobs: submit (a model or G-code), list, show, remove, move, next; the bundled samples."""
from __future__ import annotations

import argparse
import queue
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fabric import schemas as s
from fabric.cli.inputs import read_input, submit_source
from fabric.cli.output import StatusLine, emit
from fabric.cli.pipeline_cmds import parse_sets
from fabric.cli.progress import print_progress
from fabric.client import Client
from fabric.client.follow import follow_print
from fabric.printjobs.history import estimate_text, material_text, override_lines, segment_lines, state_text
from fabric.samples import SAMPLES_DIR, Sample, samples
from fabric.schemas.states import PrintJob
from fabric.wire.errors import NotFound, ValidationError

__all__ = ["register", "submit_and_follow", "add_follow_args"]



def _shown(reply: Any, a: argparse.Namespace, text: Callable[[Any], str]) -> int:
    """Print a reply (JSON or text) and succeed."""
    emit(reply, a.json, text)
    return 0

def _settled(rec: s.JobRecord) -> bool:
    """Submission is over: the job is on the station, prepared and waiting for something, or ended."""
    return (rec.state.on_station or rec.state.ended
            or (rec.prepared and rec.waiting_for != ""))


def _show_change(quiet: bool, status: StatusLine):
    if quiet:
        return None

    def show(rec: s.JobRecord) -> None:     # redrawn in place on a terminal; a line per change when piped
        status.draw(f"  {rec.state:<10} {rec.stage[:48]:<48}")
    return show


def _when(t_s: float) -> str:
    return time.strftime("%H:%M:%S", time.localtime(t_s)) if t_s else "-"


def _row(rec: s.JobRecord) -> str:
    took = f"{rec.sim_elapsed_s:8.1f}" if rec.started_s else "       -"
    return (f"{rec.job_id}  {rec.state:<11} {_when(rec.created_s)}  {took}  {rec.deposited_mm3:10.0f}  "
            f"{rec.filename[:28]:<28}  {rec.reason or rec.stage}")


def _list_text(jobs: s.JobList) -> str:
    total = jobs.total if jobs.total >= 0 else len(jobs.jobs)     # -1: the reply holds every job
    if not jobs.jobs:
        return "no jobs" if total == 0 else f"no jobs from {jobs.offset + 1} (of {total})"
    head = f"{'job':<12}  {'state':<11} {'created':<8}  {'sim s':>8}  {'mm3':>10}  {'file':<28}  stage / reason"
    lines = [head] + [_row(r) for r in jobs.jobs]
    if len(jobs.jobs) < total:
        lines.append(f"showing {jobs.offset + 1}-{jobs.offset + len(jobs.jobs)} of {total}")
    return "\n".join(lines)


def resolve_job_id(c: Client, job_id: str) -> str:
    """A job's whole id from a unique prefix of it (the console and lists may show fewer than 12 digits)."""
    job_id = job_id.strip()
    if len(job_id) >= 12:
        return job_id
    if not job_id:
        raise ValidationError("give a job id (fabric-cli job list shows them)", field="job_id")
    matches = [r.job_id for r in c.jobs(0, s.MAX_JOBS_PAGE).jobs if r.job_id.startswith(job_id)]
    if len(matches) == 1:
        return matches[0]
    if not matches:
        raise NotFound(f"no job id starts with {job_id!r} (fabric-cli job list shows them)", job_id=job_id)
    raise ValidationError(f"job id {job_id!r} is the start of {len(matches)} jobs ({', '.join(matches[:5])}"
                          f"{', ...' if len(matches) > 5 else ''}): give more of it", field="job_id",
                          matches=matches[:20])


def _record_text(rec: s.JobRecord) -> str:
    source = f"{rec.source}, curved layers" if rec.layers == "curved" else rec.source
    lines = [f"job {rec.job_id}: {rec.filename} ({source}) {state_text(rec)}",
             f"  stage      {rec.stage}"]
    if rec.reason:
        lines.append(f"  reason     {rec.reason}")
    lines.append(f"  created    {_when(rec.created_s)}   started {_when(rec.started_s)}   ended {_when(rec.ended_s)}")
    if rec.started_s:
        lines.append(f"  duration   {rec.sim_elapsed_s:.1f} s simulated, {rec.wall_elapsed_s:.1f} s wall")
        lines.append(f"  material   {material_text(rec)}")
    if rec.plan is not None:
        lines.append(f"  plan       {rec.plan.moves} moves, {rec.plan.layers} layers, "
                     f"{rec.plan.extruded_mm3:.0f} mm3 of {rec.plan.filament_diameter_mm:g} mm filament "
                     f"({rec.plan.material_source}), {estimate_text(rec.plan.estimate_s)}")
    if rec.segments:
        lines.append("  runs")
        lines += [f"    {line}" for line in segment_lines(rec)]
    if rec.live_overrides:
        lines.append("  overrides")
        lines += [f"    {line}" for line in override_lines(rec)]
    if rec.error is not None:
        lines.append(f"  error      [{rec.error.code}] {rec.error.message}")
    return "\n".join(lines)


def _samples_text(found: list[Sample]) -> str:
    lines = [f"{'part':<18} {'triangles':>9}  {'size x y z mm':<16}  what"]
    lines += [f"{x.name:<18} {x.triangles:>9}  {'x'.join(f'{v:.0f}' for v in x.size_mm):<16}  {x.description}"
              for x in found]
    lines.append(f"in {SAMPLES_DIR} (fabric-cli job submit {found[0].path if found else 'FILE'} --start)")
    return "\n".join(lines)


def _cmd_samples(a: argparse.Namespace) -> int:
    found = samples()
    emit([{"name": x.name, "path": str(x.path), "triangles": x.triangles, "size_mm": list(x.size_mm),
           "description": x.description} for x in found], a.json, lambda _: _samples_text(found))
    return 0


def cmd_submit(c: Client, a: argparse.Namespace) -> int:
    # no --source: the supervisor takes it from the file name (JobSubmit.source "", as any client may send);
    # a file larger than INLINE_MAX_BYTES is uploaded in pieces first and named by its upload id
    req = s.JobSubmit(**submit_source(c, read_input(a.file)), filename=Path(a.file).name, source=a.source or "",
                      profile=a.profile, backend=a.backend, overrides=parse_sets(a.set), start=a.start, rtf=a.rtf,
                      filament_diameter_mm=a.filament_diameter, layers=a.layers)
    return submit_and_follow(c, a, req)


def submit_and_follow(c: Client, a: argparse.Namespace, req: s.JobSubmit) -> int:
    """Submit ``req``; with ``--wait`` or ``--follow`` (``a``) show the job until it settles or the print ends."""
    acc = c.submit(req)
    if not (a.wait or a.follow):
        emit(acc, a.json, lambda r: f"job {r.job_id} queued")
        return 0
    with StatusLine() as status:
        rec = c.wait_print_job(acc.job_id, _settled, timeout=a.timeout or 3600.0,
                               on_change=_show_change(a.json, status))
    result: dict = {"job": rec}
    if a.follow and (rec.state.printing or rec.state == PrintJob.LOADED) and a.start:
        try:
            with print_progress(c, acc.job_id, quiet=a.json):    # layer, %, volume, ETA on stderr
                result["end"] = follow_print(c, timeout_s=a.timeout)
        except queue.Empty:
            result["end"] = None
        # the supervisor applies the same end event to the record: wait for it to say so
        result["job"] = c.wait_print_job(acc.job_id, lambda r: False, timeout=60.0)
        result["time"] = c.time()
    emit(result, a.json, lambda r: _record_text(r["job"])
         + (f"\n  print {r['end'].kind} at t={r['end'].t_sim_s:.1f} s" if r.get("end") else ""))
    return 1 if result["job"].state == PrintJob.FAILED else 0


def add_follow_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--wait", action="store_true", help="wait until the job is prepared or loaded")
    p.add_argument("--follow", action="store_true", help="with --start: wait for the print to end")
    p.add_argument("--timeout", type=float, default=None)


def register(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    job = sub.add_parser("job", help="print jobs: a durable queue (slice -> plan -> check -> load -> print)")
    jsub = job.add_subparsers(dest="job_cmd", required=True)
    p = jsub.add_parser("submit", parents=[common], help="queue a model (STL/OBJ/3MF) or a G-code file")
    p.add_argument("file")
    p.add_argument("--profile", default="taz-pla-medium")
    p.add_argument("--backend", default="builtin", choices=s.pipeline.BACKENDS)
    p.add_argument("--layers", default="planar", choices=s.pipeline.LAYER_MODES,
                   help="planar layers, or curved layers with a tilted nozzle (a model; builtin slicer)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a profile key (a model)")
    p.add_argument("--filament-diameter", type=float, default=None, metavar="MM",
                   help="the filament's diameter (e.g. 2.85), for G-code that does not state it; a model is sliced "
                        "for it")
    p.add_argument("--start", action="store_true", help="start printing once loaded (when the plate is clear)")
    p.add_argument("--rtf", type=float, default=1.0,
                   help="real-time factor of the print (default 1: real time, as on the wire; 0 = as fast as possible)")
    p.add_argument("--source", choices=s.pipeline.JOB_SOURCES, default=None,
                   help="model or gcode (default: from the file name: .gcode/.gco/.g/.nc, .stl/.obj/.3mf)")
    add_follow_args(p)
    p.set_defaults(run=cmd_submit)
    p = jsub.add_parser("list", parents=[common], help="the queue and the history, a page at a time")
    p.add_argument("--offset", type=int, default=0, help="skip this many jobs (queue order)")
    p.add_argument("--limit", type=int, default=100, help=f"show at most this many (up to {s.MAX_JOBS_PAGE})")
    p.add_argument("--state", action="append", default=[], choices=s.PRINT_JOB_STATES,
                   help="only jobs in this state (repeat for several)")
    p.set_defaults(run=lambda c, a: _shown(c.jobs(a.offset, a.limit, a.state), a, _list_text))
    for name in ("show", "status"):
        p = jsub.add_parser(name, parents=[common], help="one job's whole record (its runs, its overrides)")
        p.add_argument("job_id", help="the job's id, or a unique start of it")
        p.set_defaults(run=lambda c, a: _shown(c.job(resolve_job_id(c, a.job_id)), a, _record_text))
    p = jsub.add_parser("remove", parents=[common], help="remove a job that is not on the station")
    p.add_argument("job_id", help="the job's id, or a unique start of it")
    p.set_defaults(run=lambda c, a: _shown(c.job_remove(resolve_job_id(c, a.job_id)), a, lambda r: r.message))
    p = jsub.add_parser("move", parents=[common], help="move a waiting job to a place in the queue (0 = next)")
    p.add_argument("job_id", help="the job's id, or a unique start of it")
    p.add_argument("position", type=int)
    p.set_defaults(run=lambda c, a: _shown(c.job_move(resolve_job_id(c, a.job_id), a.position), a, _list_text))
    p = sub.add_parser("samples", parents=[common], help="the parts bundled with am-fabric, to print first")
    p.set_defaults(local=_cmd_samples)
    p = jsub.add_parser("next", parents=[common],
                        help="the plate is clear: load the next job (started if submitted with --start)")
    p.set_defaults(run=lambda c, a: _shown(c.job_next(), a, lambda r: r.message))
