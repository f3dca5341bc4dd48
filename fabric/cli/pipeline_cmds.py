"""CLI commands for the pipeline: slice, plan (+ exports), print jobs."""
from __future__ import annotations

import argparse
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import BinaryIO

from fabric import schemas as s
from fabric.cli.inputs import LargeInput, gcode_source, model_source, read_input
from fabric.cli.output import StatusLine, emit
from fabric.client import Client
from fabric.wire.errors import BadRequest

__all__ = ["register", "parse_sets", "read_input"]

EXPORT_FLAGS = {"csv": "csv", "rapid": "rapid", "krl": "krl", "urscript": "urscript"}


def foreign_maker(fmt: str, native: str) -> str | None:
    """Whose robot language export ``fmt`` is, when that is another brand's than the cell's (``native``); None
    for CSV (anyone's), the cell's own, or an older planner's summary that names no native export."""
    from fabric.robot.brands import language_maker  # fabric.robot is the services' package: not at import
    maker = language_maker(fmt)
    return maker if maker is not None and native and fmt != native else None


def parse_sets(items: list[str] | None) -> dict[str, str]:
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise BadRequest(f"--set expects key=value, got {item!r}", value=item)
        out[key.strip()] = value.strip()
    return out


def _cycle_time(r: s.PlanSummary) -> str:
    """The estimate in words: none when the program cannot run (the summary holds -1)."""
    return f"{r.estimate_s:.1f} s" if r.estimate_s >= 0 else "n/a (not runnable)"


def _progress(quiet: bool, line: StatusLine):
    if quiet:
        return None
    def show(st: s.JobStatus) -> None:     # piped: the stage once, not each percentage
        stage = st.stage or st.kind
        line.draw(f"  {stage:<20} {100 * st.progress_r:5.1f} %", piped=f"  {stage}")
    return show


def cmd_slice(c: Client, a: argparse.Namespace) -> int:
    req = s.SliceRequest(**model_source(c, read_input(a.model)), filename=Path(a.model).name, profile=a.profile,
                         backend=a.backend, overrides=parse_sets(a.set),
                         center_xy_mm=list(a.center) if a.center else None, layers=a.layers)
    acc = c.slice(req)
    with StatusLine() as line:
        st = c.wait_job("slicer", acc.job_id, on_progress=_progress(a.json, line))
    res = c.slice_result(st.result_id)
    gcode = c.artifact("slicer", st.result_id)
    Path(a.output).write_bytes(gcode.data)
    emit(res, a.json, lambda r: (f"{a.output}: {r.layers} layers, {r.extruded_mm3:.0f} mm3 "
                                 f"({r.filament_mm:.0f} mm filament) with {r.backend} in {r.elapsed_s:.2f} s"
                                 + "".join(f"\n  {line}" for line in curved_lines(r.curved))
                                 + "".join(f"\n  warning: {w}" for w in r.warnings)))
    return 0


def curved_lines(fig: dict[str, float]) -> list[str]:
    """A curved slice's figures in words, planar beside curved (empty for planar layers)."""
    if not fig:
        return []
    g = lambda k: fig.get(k, float("nan"))       # noqa: E731
    return [f"curved layers: overhang {g('planar_overhang_mm2'):.0f} mm2 planar -> {g('overhang_mm2'):.0f} mm2 "
            f"({100 * g('overhang_reduction_r'):.0f} % less), thickness {g('thickness_min_mm'):.3f}.."
            f"{g('thickness_max_mm'):.3f} mm (ratio {g('thickness_ratio_r'):.2f})",
            f"nozzle tilt up to {g('max_tilt_deg'):.1f} deg, neighbouring axes within {g('max_neighbour_deg'):.1f} "
            f"deg, top-surface cusp mean {g('planar_cusp_mean_mm'):.3f} -> {g('cusp_mean_mm'):.3f} mm, max "
            f"{g('planar_cusp_max_mm'):.3f} -> {g('cusp_max_mm'):.3f} mm"]


def plan_file(c: Client, data: bytes | LargeInput, filename: str, a: argparse.Namespace,
              exports: dict[str, BinaryIO] | None = None) -> tuple[s.PlanSummary, dict[str, int]]:
    """Plan G-code; returns its summary and the bytes of each export written into ``exports`` (format ->
    binary stream). The exports are asked for by job id at once, so the planner streams each as soon as
    the program is final (the CSV once its times are), while the job goes on with its cycle time and id."""
    req = s.PlanRequest(**gcode_source(c, data), filename=filename, offset_mm=list(a.offset), speed_r=a.speed,
                        tilt_deg=list(a.tilt), rot_step_deg=a.rot_step, filament_diameter_mm=a.filament_diameter,
                        linear_tol_mm=a.linear_tol,
                        allow_off_plate=a.allow_off_plate)
    acc = c.plan(req)
    with StatusLine() as line, ThreadPoolExecutor(max_workers=1, thread_name_prefix="plan-progress") as follow:
        job = follow.submit(c.wait_job, "planner", acc.job_id, on_progress=_progress(a.json, line))
        sizes = {fmt: c.export_to("", fmt, out, a.module_targets, job_id=acc.job_id)
                 for fmt, out in (exports or {}).items()}
        st = job.result()
    return c.plan_summary(st.result_id), sizes


def cmd_plan(c: Client, a: argparse.Namespace) -> int:
    from fabric.planning.memory import keep_freed_memory  # only this command needs these
    from fabric.planning.post.atomic import AtomicFiles
    keep_freed_memory()                     # export chunks reuse the pages of the ones before
    data = read_input(a.gcode)
    with AtomicFiles() as files:          # every export file, or none (temporary files renamed at the end)
        targets = {fmt: getattr(a, fmt) for fmt in EXPORT_FLAGS if getattr(a, fmt)}
        summary, _sizes = plan_file(c, data, Path(a.gcode).name, a,
                                    {fmt: files.open(out) for fmt, out in targets.items()})
    written = targets
    result = {"summary": summary, "written": written}

    def text(_):
        r = summary
        lines = [f"program {r.program_id[:12]}: {r.targets} targets, {r.moves} moves, {r.layers} layers, "
                 f"cycle time {_cycle_time(r)}, {r.extruded_mm3:.0f} mm3, feasible {100 * r.feasible_r:.2f} %"]
        stated = {"option": "as asked", "gcode": "as the G-code states", "assumed": "ASSUMED"}[r.material_source]
        lines.append(f"material {r.material or 'unnamed'}, filament {r.filament_diameter_mm:g} mm ({stated})"
                     + (f", {r.mass_g:.1f} g" if r.mass_g is not None else ""))
        lines += [f"warning: {w}" for w in r.warnings]
        fs = r.first_slowed
        if fs is not None:
            lines.append(f"{r.slowed_targets} moves slowed to respect joint speed limits, first at G-code line "
                         f"{fs.gcode_line} (A{fs.joint})")
        fu = r.first_unreachable
        if fu is not None:
            lines.append(f"NOT RUNNABLE: first unreachable target at G-code line {fu.gcode_line}: {fu.why()}"
                         f"{r.counted()}")
        if r.cold_extrusion is not None:
            lines.append(f"NOT RUNNABLE: cold extrusion: {r.cold_extrusion.message}")
        outside = {k: v for k, v in r.unreachable_by_reason.items() if k in ("off the plate", "below the plate")}
        if outside:
            lines.append(", ".join(f"{n} targets {k}" for k, n in outside.items())
                         + (" (allowed)" if r.allow_off_plate else " (--allow-off-plate to print anyway)"))
        lines += [f"wrote {fmt}: {path}" for fmt, path in written.items()]
        lines += [f"warning: {path} is {fmt} ({maker}'s controllers); this cell's controller runs {r.native_export}"
                  for fmt, path in written.items() if (maker := foreign_maker(fmt, r.native_export))]
        return "\n".join(lines)
    emit(result, a.json, text)
    return 0 if summary.runnable else 2


def register(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser("slice", parents=[common], help="slice a model (STL/OBJ/3MF) into G-code")
    p.add_argument("model")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--backend", default="builtin", choices=s.pipeline.BACKENDS)
    p.add_argument("--profile", default="taz-pla-medium")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a profile key")
    p.add_argument("--center", nargs=2, type=float, metavar=("X_MM", "Y_MM"), help="part centre on the plate")
    p.add_argument("--layers", default="planar", choices=s.pipeline.LAYER_MODES,
                   help="planar layers, or curved layers with a tilted nozzle (builtin; multi-axis G-code)")
    p.set_defaults(run=cmd_slice)

    p = sub.add_parser("plan", parents=[common], help="plan G-code into a robot program; export it")
    p.add_argument("gcode")
    for fmt in EXPORT_FLAGS:
        p.add_argument(f"--{fmt}", metavar="OUT", help=f"write the {fmt} export")
    p.add_argument("--offset", nargs=3, type=float, default=(0.0, 0.0, 0.0), metavar=("X", "Y", "Z"))
    p.add_argument("--tilt", nargs=2, type=float, default=(0.0, 0.0), metavar=("RX_DEG", "RY_DEG"))
    p.add_argument("--speed", type=float, default=1.0, help="feed-rate factor")
    p.add_argument("--rot-step", type=float, default=15.0, help="free-rotation search step (deg)")
    p.add_argument("--linear-tol", type=float, default=0.1, metavar="MM",
                   help="a linear move whose joints, interpolated between its rows, would stray further than this "
                        "from its straight line is planned in pieces (default 0.1 mm)")
    p.add_argument("--module-targets", type=int, default=5000, help="targets per RAPID/KRL module")
    p.add_argument("--filament-diameter", type=float, default=None, metavar="MM",
                   help="filament diameter (default: as the G-code states it, else 1.75 mm with a warning)")
    p.add_argument("--allow-off-plate", action="store_true",
                   help="plan targets off the plate or below its surface as runnable (they are still counted)")
    p.set_defaults(run=cmd_plan)
