"""The certified sweep of multi-axis programs (curved layers, a tilted nozzle) against planar ones, same run.

The planar rows: the bundled sample part, sliced planar with both profiles, planned on the paper's cell
``irb140`` (as ``collision_bench.py`` measures it). The curved rows: multi-axis G-code files, planned on
``irb140-multiaxis``; by default the four test shapes of ``fabric/slicing/curved/shapes.py`` sliced with curved
layers (``taz-pla-medium``). A program that is not collision-free is timed up to its first hit: the sweep
certifies the rows before the hit's row (its first hit ends a sweep, and a curved slice of today may touch the
plate early). ``FILE@LAYER`` keeps the approach and the rows from layer ``LAYER`` on: the curved layers of a
part whose lower layers hit, on their own (their beads only).

Segments certified per second, best of 3: wall time and this process's CPU time (the machine may be shared:
compare the ratios, measured in one run). Writes ``docs/bench/collision_curved.md`` and ``.json``.

    .venv/bin/python tools/bench/collision_curved_bench.py [FILE.gcode[@LAYER] ...]
"""
from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from fabric.collision.certify import Certifier  # noqa: E402
from fabric.demo import sample_model  # noqa: E402
from fabric.motion.program import PRINT, Program  # noqa: E402
from fabric.planning import PlanOptions, plan_gcode  # noqa: E402
from fabric.robot.cell import Cell  # noqa: E402
from fabric.slicing import load_profile, slice_model  # noqa: E402

PLANAR_PROFILES = ("robot-1.2mm", "taz-pla-medium")
CURVED_PROFILE = "taz-pla-medium"
CURVED_CELL = "irb140-multiaxis"
RUNS = 3


def timed(cert: Certifier, program: Program) -> dict:
    """Best of ``RUNS`` sweeps (after a warm one): the result's figures, wall and CPU seconds."""
    cert.sweep_program(program)
    walls, cpus = [], []
    for _ in range(RUNS):
        t0 = time.process_time()
        res = cert.sweep_program(program)
        cpus.append(time.process_time() - t0)
        walls.append(res.elapsed_s)
    hit = res.first_hit
    wall_s, cpu_s = min(walls), min(cpus)
    return {
        "rows": len(program), "segments": res.segments, "beads": res.beads, "wall_s": wall_s, "cpu_s": cpu_s,
        "segments_per_s": res.segments / wall_s, "segments_per_cpu_s": res.segments / cpu_s,
        "collision_free": res.collision_free, "clearance_mm": res.clearance_mm,
        "clearance_body": res.clearance_body, "configs": res.configs,
        "hit": None if hit is None else {"gcode_line": int(program.gcode_line[hit.row]), "body": hit.body,
                                         "other": hit.other},
    }


def from_layer(program: Program, layer: int) -> Program:
    """The approach, then the rows from layer ``layer``'s first row on (the layers under it left out)."""
    first_print = int(np.flatnonzero(program.section == PRINT)[0])
    start = int(np.flatnonzero(program.layer == layer)[0])
    out = Program.concat([program.slice(0, first_print), program.slice(start, len(program))])
    out.meta.update(program.meta)
    return out


def curved_inputs(args: list[str], tmp: Path) -> list[tuple[str, bytes, int | None]]:
    """(name, G-code, first layer or None) per curved program: the files given, or the test shapes sliced."""
    out = []
    for arg in args:
        path, _, layer = arg.partition("@")
        name = Path(path).stem + (f" from layer {layer}" if layer else "")
        out.append((name, Path(path).read_bytes(), int(layer) if layer else None))
    if out:
        return out
    from fabric.slicing.curved.shapes import SHAPES
    for name, make in SHAPES.items():
        stl = tmp / f"{name}.stl"
        make().export(stl)
        gcode = slice_model(stl.read_bytes(), stl.name, load_profile(CURVED_PROFILE), layers="curved").gcode
        out.append((name, gcode if isinstance(gcode, bytes) else gcode.encode(), None))
    return out


def main(argv: list[str]) -> dict:
    planar_cell, curved_cell = Cell.builtin("irb140"), Cell.load_or_builtin(CURVED_CELL)
    model = sample_model()
    planar = {}
    print("planar, the sample part on irb140:", flush=True)
    cert = Certifier(planar_cell)
    for profile in PLANAR_PROFILES:
        gcode = slice_model(model.read_bytes(), model.name, load_profile(profile)).gcode
        program = plan_gcode(gcode if isinstance(gcode, bytes) else gcode.encode(), planar_cell, PlanOptions()).program
        planar[profile] = timed(cert, program)
        _line(f"sample {profile}", planar[profile])
    base = statistics.mean(v["segments_per_cpu_s"] for v in planar.values())
    curved = {}
    print(f"curved, on {CURVED_CELL}:", flush=True)
    cert = Certifier(curved_cell)
    with tempfile.TemporaryDirectory(prefix="collision-curved-") as td:
        for name, gcode, layer in curved_inputs(argv, Path(td)):
            program = plan_gcode(gcode, curved_cell, PlanOptions()).program
            if layer is not None:
                program = from_layer(program, layer)
            whole = cert.sweep_program(program)
            entry: dict = {"whole_segments": whole.segments, "whole_free": whole.collision_free}
            if whole.first_hit is not None:           # time what is certified: the rows before the hit's row
                hit = whole.first_hit
                entry["first_hit"] = {"gcode_line": int(program.gcode_line[hit.row]), "body": hit.body,
                                      "other": hit.other, "row": hit.row}
                program = program.slice(0, hit.row)
            entry.update(timed(cert, program))
            entry["planar_over_curved"] = base / entry["segments_per_cpu_s"]
            curved[name] = entry
            _line(name, entry)
    result = {"host": platform.node(), "cpus": os.cpu_count(), "python": platform.python_version(),
              "load_avg": os.getloadavg(), "date": time.strftime("%Y-%m-%d %H:%M"), "runs": RUNS,
              "planar": planar, "curved": curved, "planar_segments_per_cpu_s": base,
              "nozzle_mm": curved_cell.robot.tool.nozzle_diameter_mm}
    _write(result, argv)
    return result


def _line(name: str, v: dict) -> None:
    hit = v.get("first_hit")
    print(f"  {name}: {v['segments']:,} segments, {v['segments_per_s']:,.0f}/s wall, "
          f"{v['segments_per_cpu_s']:,.0f}/s CPU, clearance {v['clearance_mm']:.3f} mm ({v['clearance_body']})"
          + (f"; first hit at G-code line {hit['gcode_line']} ({hit['body']} - {hit['other']})" if hit else ""),
          flush=True)


def _write(r: dict, argv: list[str]) -> None:
    out = ROOT / "docs" / "bench"
    (out / "collision_curved.json").write_text(json.dumps(r, indent=1) + "\n")
    rows_p = "\n".join(
        f"| sample part, {name} | {v['segments']:,} | {v['cpu_s']:.2f} | **{v['segments_per_cpu_s']:,.0f}** | "
        f"{v['segments_per_s']:,.0f} | 1 | {v['clearance_mm']:.3f} ({v['clearance_body']}) | none |"
        for name, v in r["planar"].items())
    rows_c = "\n".join(
        f"| {name} | {v['segments']:,} of {v['whole_segments']:,} | {v['cpu_s']:.2f} "
        f"| **{v['segments_per_cpu_s']:,.0f}** | {v['segments_per_s']:,.0f} | {v['planar_over_curved']:.1f} "
        f"| {v['clearance_mm']:.3f} ({v['clearance_body']}) |"
        + (f" line {v['first_hit']['gcode_line']}, {v['first_hit']['body']} - {v['first_hit']['other']} |"
           if "first_hit" in v else " none |")
        for name, v in r["curved"].items())
    header = (f"| program | segments certified | CPU (s, best of {r['runs']}) | segments / CPU s "
              "| segments / s (wall) | planar / this | certified clearance (mm) | first hit of the whole program |")
    inputs = "the files named" if argv else f"the four test shapes sliced curved ({CURVED_PROFILE})"
    md = f"""# Collision check: multi-axis programs against planar ones

`.venv/bin/python tools/bench/collision_curved_bench.py {" ".join(argv)}` on {r['host']} ({r['cpus']} CPUs,
Python {r['python']}, load average {r['load_avg'][0]:.1f} at the end), {r['date']}. Curved inputs: {inputs}.
The machine is shared: compare the ratios, each measured in one run; CPU time is this process's.

Planar: the sample part sliced planar, on `irb140`. Curved: multi-axis programs (curved layers, the nozzle
tilted up to 45 deg and more, each bead laid along its own nozzle axis), on `{CURVED_CELL}`
(a slender nozzle, {r['nozzle_mm']:g} mm across). A program that is not collision-free is certified up to its
first hit (the rows before the hit's row), which is what a sweep does before it stops; `@LAYER`: the rows from
that layer on, alone.
A few thousand segments are too few to say much: the sweep's fixed costs (the approach's joint moves, the
broad phase, the first batch's hulls) are most of their time.

{header}
|---|---:|---:|---:|---:|---:|---|---|
{rows_p}
{rows_c}
"""
    (out / "collision_curved.md").write_text(md)


if __name__ == "__main__":
    main(sys.argv[1:])
