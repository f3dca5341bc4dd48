"""``fabric-cli check FILE``: plan a G-code file (slicing a model first) and certify it for collisions.

The same check the supervisor runs before a job may load: every motion of the
program, every robot body, the tool and the nozzle, against the table, the
plate, the part as printed bead by bead and the robot itself. It prints
``collision-free, certified clearance X mm`` or the first hit (G-code line,
move, bodies, where, when) and exits 0, or ``COLLISION_EXIT`` on a hit. A
file that cannot be planned (unreachable, extruding cold) is a typed error.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fabric import schemas as s
from fabric.cli.inputs import GCODE_SUFFIXES, model_source, read_input
from fabric.cli.output import emit
from fabric.cli.pipeline_cmds import plan_file
from fabric.client import Client
from fabric.wire.errors import ColdExtrusionError, UnreachableError

__all__ = ["register", "report_text", "COLLISION_EXIT"]

COLLISION_EXIT = 2          # a hit (1 is an error, as for every command)


def report_text(r: s.CollisionReport) -> str:
    """The verdict in words: the clearance and where it is smallest, or the first hit."""
    h = r.first_hit
    if h is not None:
        return f"COLLISION at {h.message or f'G-code line {h.gcode_line}: {h.body_a} hits {h.body_b}'}"
    if r.min_distance_mm < 0:
        return "collision-free: nothing moves"
    where = [w for w in (r.clearance_body, f"G-code line {r.clearance_gcode_line}"
                         if r.clearance_gcode_line >= 0 else "",
                         f"layer {r.clearance_layer + 1}" if r.clearance_layer >= 0 else "") if w]
    line = f"collision-free, certified clearance {r.min_distance_mm:.3f} mm"
    return line + (f" ({', '.join(where)})" if where else "")


def _slice(c: Client, path: str, a: argparse.Namespace) -> s.PlanSummary:
    """Slice the model, then plan the G-code the slicer made (by its id: it stays on the fabric)."""
    req = s.SliceRequest(**model_source(c, read_input(path)), filename=Path(path).name, profile=a.profile,
                         backend=a.backend, layers=a.layers)
    st = c.wait_job("slicer", c.slice(req).job_id)
    plan = s.PlanRequest(gcode_id=st.result_id, filename=Path(path).with_suffix(".gcode").name,
                         offset_mm=list(a.offset), speed_r=a.speed, tilt_deg=list(a.tilt), rot_step_deg=a.rot_step,
                         filament_diameter_mm=a.filament_diameter, allow_off_plate=a.allow_off_plate,
                         linear_tol_mm=a.linear_tol)
    done = c.wait_job("planner", c.plan(plan).job_id)
    return c.plan_summary(done.result_id)


def _runnable(summary: s.PlanSummary) -> None:
    """A program the robot cannot run is not checked: its first problem, as a typed error."""
    fu = summary.first_unreachable
    if fu is not None:
        raise UnreachableError(f"the program has unreachable targets, the first at G-code line {fu.gcode_line}: "
                               f"{fu.why()}{summary.counted()}", **fu.error_details())
    cold = summary.cold_extrusion
    if cold is not None:
        raise ColdExtrusionError(f"the program would extrude cold: {cold.message}", **{
            k: v for k, v in s.to_plain(cold).items() if k != "message"})


def cmd_check(c: Client, a: argparse.Namespace) -> int:
    path = a.file
    if Path(path).suffix.lower() in GCODE_SUFFIXES:
        quiet = argparse.Namespace(**{**vars(a), "json": True})   # no progress line: one verdict, or one error
        summary, _ = plan_file(c, read_input(path), Path(path).name, quiet)
    else:
        summary = _slice(c, path, a)
    _runnable(summary)
    report = c.check(s.CollisionRequest(program_id=summary.program_id, tolerance_mm=a.tolerance))

    def text(_) -> str:
        lines = [report_text(report)]
        lines.append(f"  program {summary.program_id[:12]}: {summary.moves} moves, {summary.layers} layers; "
                     f"{report.segments} segments and {report.beads} beads certified in {report.elapsed_s:.2f} s")
        if report.exemption:
            lines.append(f"  not checked: {report.exemption}")
        return "\n".join(lines)
    emit({"summary": summary, "collisions": report}, a.json, text)
    if not a.json:
        sys.stdout.flush()
    return 0 if report.collision_free else COLLISION_EXIT


def register(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser("check", parents=[common],
                       help="plan a G-code file (or slice a model first) and certify it for collisions",
                       description="Plan FILE (G-code; a model is sliced first) and certify every motion against "
                                   "the table, the plate, the part as printed and the robot itself. Exit status "
                                   f"0: collision-free; {COLLISION_EXIT}: a hit; 1: an error.")
    p.add_argument("file", help="G-code (.gcode, .gco, .g, .nc) or a model (STL, OBJ, 3MF) to slice first")
    p.add_argument("--tolerance", type=float, default=0.01, metavar="MM",
                   help="bodies this close count as touching (default 0.01 mm)")
    p.add_argument("--profile", default="taz-pla-medium", help="slicing profile, for a model")
    p.add_argument("--backend", default="builtin", choices=s.pipeline.BACKENDS, help="slicer, for a model")
    p.add_argument("--layers", default="planar", choices=s.pipeline.LAYER_MODES,
                   help="planar, or curved layers with a tilted nozzle (a model; builtin slicer)")
    p.add_argument("--offset", nargs=3, type=float, default=(0.0, 0.0, 0.0), metavar=("X", "Y", "Z"))
    p.add_argument("--tilt", nargs=2, type=float, default=(0.0, 0.0), metavar=("RX_DEG", "RY_DEG"))
    p.add_argument("--speed", type=float, default=1.0, help="feed-rate factor")
    p.add_argument("--rot-step", type=float, default=15.0, help="free-rotation search step (deg)")
    p.add_argument("--linear-tol", type=float, default=0.1, metavar="MM",
                   help="a linear move whose joints, interpolated between its rows, would stray further than this "
                        "from its straight line is planned in pieces (default 0.1 mm)")
    p.add_argument("--filament-diameter", type=float, default=None, metavar="MM",
                   help="filament diameter (default: as the G-code states it)")
    p.add_argument("--allow-off-plate", action="store_true", help="plan targets off the plate as runnable")
    p.set_defaults(run=cmd_check)
