"""Collision benchmark: the certified sweep against version 1's sampled sweep, and against planning.

Three figures, each against a baseline measured in the same run:

1. the bundled sample part, sliced with two profiles (``robot-1.2mm``: 0.6 mm
   layers; ``taz-pla-medium``: 0.25 mm layers, the slicer's default), through
   the CLI against a cell of processes: ``fabric-cli check FILE`` (plan, then
   the certified sweep against the part's own beads) against
   ``fabric-cli plan FILE``, alternating, ``n_runs`` each; the ratio of the
   medians (target: at most 3);
2. the same programs in process: path segments certified per second;
3. a raster of a million moves (``plan_bench.write_raster``: 5 mm extruding
   segments, ~16,000 a layer): the certified sweep against version 1's sampled
   sweep (``fabric.services.collision.sweep_program``: joint configurations every
   2 degrees of joint travel against one box per layer), both in this process.

Writes ``docs/bench/collision.md`` and ``collision.json``.

    .venv/bin/python tools/bench/collision_bench.py [n_moves] [n_runs]
"""
from __future__ import annotations

import json
import os
import platform
import resource
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from plan_bench import write_raster  # noqa: E402  (the million-move raster of the planning benchmark)

from fabric.cli.up import CellProcesses  # noqa: E402
from fabric.collision.certify import Certifier  # noqa: E402
from fabric.collision.sweep import CollisionChecker  # noqa: E402
from fabric.demo import sample_model  # noqa: E402
from fabric.planning import PlanOptions, plan_gcode, plan_gcode_file  # noqa: E402
from fabric.robot.cell import Cell  # noqa: E402
from fabric.services.collision import sweep_program  # noqa: E402
from fabric.slicing import load_profile, slice_model  # noqa: E402
from fabric.wire.config import SessionSettings  # noqa: E402

PROFILES = ("robot-1.2mm", "taz-pla-medium")


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _cli(args: list[str]) -> tuple[float, int, str]:
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "fabric.cli.main", *args], capture_output=True, text=True,
                       timeout=900)
    return time.perf_counter() - t0, r.returncode, r.stdout.splitlines()[0] if r.stdout else r.stderr.strip()


def through_the_cli(files: dict[str, Path], n_runs: int, tmp: Path) -> dict:
    """``fabric-cli plan`` and ``fabric-cli check`` of each file against a cell of processes, alternating."""
    st = SessionSettings(connect=[f"tcp/127.0.0.1:{_free_port()}"], cell=f"b{uuid.uuid4().hex[:8]}")
    cell = CellProcesses(st, log_dir=tmp / "logs", data_dir=tmp / "data")
    cell.start(deadline_s=120.0)
    try:
        conn = replace(st, mode="client").to_args()
        out = {}
        for name, path in files.items():
            _cli(["check", str(path), *conn])                           # warm the services (imports, caches)
            plan, check = [], []
            verdict = ""
            for _ in range(n_runs):
                t, rc, _line = _cli(["plan", str(path), *conn])
                assert rc == 0, _line
                plan.append(t)
                t, rc, verdict = _cli(["check", str(path), *conn])
                assert rc == 0, verdict
                check.append(t)
            out[name] = {"plan_s": plan, "check_s": check, "plan_median_s": statistics.median(plan),
                         "check_median_s": statistics.median(check),
                         "ratio": statistics.median(check) / statistics.median(plan), "verdict": verdict}
            print(f"  {name}: plan {out[name]['plan_median_s']:.2f} s, check {out[name]['check_median_s']:.2f} s "
                  f"(x{out[name]['ratio']:.2f}): {verdict}", flush=True)
        return out
    finally:
        cell.stop()


def in_process(programs: dict, cell: Cell) -> dict:
    """The certified sweep of each program in this process: segments per second."""
    cert = Certifier(cell)
    out = {}
    for name, prog in programs.items():
        cert.sweep_program(prog)                                          # warm
        runs = []
        for _ in range(3):
            res = cert.sweep_program(prog)
            runs.append(res.elapsed_s)
        best = min(runs)
        out[name] = {"rows": len(prog), "segments": res.segments, "beads": res.beads, "sweep_s": runs,
                     "segments_per_s": res.segments / best, "clearance_mm": res.clearance_mm,
                     "clearance_body": res.clearance_body, "configs": res.configs, "swept_pieces": res.pieces,
                     "collision_free": res.collision_free}
        print(f"  {name}: {res.segments} segments in {best:.2f} s = {res.segments / best:,.0f} segments/s, "
              f"clearance {res.clearance_mm:.3f} mm ({res.clearance_body})", flush=True)
    return out


def million(n_moves: int, cell: Cell, tmp: Path) -> dict:
    """A raster of ``n_moves`` moves: certified sweep and version 1's sampled sweep, one after the other."""
    path = tmp / "raster.gcode"
    moves = write_raster(path, n_moves)
    t0 = time.perf_counter()
    prog = plan_gcode_file(path, cell, PlanOptions()).program
    plan_s = time.perf_counter() - t0
    print(f"  planned {moves:,} moves ({len(prog):,} rows) in {plan_s:.1f} s", flush=True)
    res = Certifier(cell).sweep_program(prog)
    print(f"  certified: {res.elapsed_s:.1f} s, {res.segments / res.elapsed_s:,.0f} segments/s, "
          f"clearance {res.clearance_mm:.3f} mm", flush=True)
    t0 = time.perf_counter()
    old = sweep_program(CollisionChecker(cell), prog, 2.0, True)
    old_s = time.perf_counter() - t0
    print(f"  sampled (version 1): {old_s:.1f} s, {old.checked_configs:,} configurations", flush=True)
    return {"moves": moves, "rows": len(prog), "plan_s": plan_s, "segments": res.segments, "beads": res.beads,
            "certified_s": res.elapsed_s, "certified_segments_per_s": res.segments / res.elapsed_s,
            "certified_clearance_mm": res.clearance_mm, "certified_clearance_body": res.clearance_body,
            "certified_configs": res.configs, "certified_pieces": res.pieces,
            "certified_free": res.collision_free, "sampled_s": old_s, "sampled_configs": old.checked_configs,
            "sampled_free": old.collision_free, "sampled_min_distance_mm": old.min_distance_mm,
            "speedup": old_s / res.elapsed_s, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def main(argv: list[str]) -> dict:
    n_moves = int(argv[0]) if argv else 1_000_000
    n_runs = int(argv[1]) if len(argv) > 1 else 5
    cell = Cell.builtin("irb140")
    model = sample_model()
    with tempfile.TemporaryDirectory(prefix="collision-bench-") as td:
        tmp = Path(td)
        files, programs = {}, {}
        for profile in PROFILES:
            gcode = slice_model(model.read_bytes(), model.name, load_profile(profile)).gcode
            files[profile] = tmp / f"sample-{profile}.gcode"
            files[profile].write_bytes(gcode if isinstance(gcode, bytes) else gcode.encode())
            programs[profile] = plan_gcode(files[profile].read_bytes(), cell, PlanOptions()).program
        print("sample part in process:", flush=True)
        inproc = in_process(programs, cell)
        print(f"sample part through the CLI ({n_runs} runs each, alternating):", flush=True)
        cli = through_the_cli(files, n_runs, tmp)
        print(f"raster of {n_moves:,} moves:", flush=True)
        big = million(n_moves, cell, tmp)
    result = {"host": platform.node(), "cpus": os.cpu_count(), "python": platform.python_version(),
              "load_avg": os.getloadavg(), "date": time.strftime("%Y-%m-%d %H:%M"), "n_runs": n_runs, "n_moves": n_moves,
              "sample_cli": cli, "sample_in_process": inproc, "raster": big}
    _write(result)
    return result


def _write(r: dict) -> None:
    out = ROOT / "docs" / "bench"
    (out / "collision.json").write_text(json.dumps(r, indent=1) + "\n")
    big, cli, inp = r["raster"], r["sample_cli"], r["sample_in_process"]
    rows_cli = "\n".join(
        f"| {name} | {c['plan_median_s']:.2f} | {c['check_median_s']:.2f} | **{c['ratio']:.2f}** | "
        f"{inp[name]['segments']:,} | {inp[name]['beads']:,} | {c['verdict']} |" for name, c in cli.items())
    rows_in = "\n".join(
        f"| {name} | {v['segments']:,} | {min(v['sweep_s']):.2f} | **{v['segments_per_s']:,.0f}** | "
        f"{v['clearance_mm']:.3f} ({v['clearance_body']}) | {v['configs']:,} | {v['swept_pieces']:,} |"
        for name, v in inp.items())
    md = f"""# Collision check: certified sweep

`.venv/bin/python tools/bench/collision_bench.py {r['n_moves']} {r['n_runs']}` on {r['host']} ({r['cpus']} CPUs,
Python {r['python']}, load average {r['load_avg'][0]:.1f} at the end), {r['date']}. The machine is shared:
compare the ratios, each measured in one run, not the seconds.

What is certified (fabric/collision/): every motion of the program (approach, prints, travels, lifts,
the return home; joint moves along the twin's own Ruckig paths) for every robot link, the tool body, the
nozzle and its tip, against the table, the plate, every bead laid before the motion (one box per bead, of
the twin's width and height) and the robot itself. The only contact not checked: the nozzle tip (radius
4 mm, the last 1 mm of the nozzle) on the layer it lays and the layers it rests on (for these planar
prints, the layer under it). Nothing is missed between checked configurations (distance lower bounds
against motion bounds, swept hulls for the nozzle along linear moves); the clearance reported is a lower
bound along the whole motion.

## The sample part through the CLI: check against plan

`fabric-cli check FILE` (plan, then the certified sweep) against `fabric-cli plan FILE`, both whole
processes against a cell of processes on this host, alternating, {r['n_runs']} runs each, medians
(target: check at most 3x plan).

| profile | plan (s) | check (s) | check / plan | segments | beads | verdict |
|---|---:|---:|---:|---:|---:|---|
{rows_cli}

## The sample part in process: segments certified per second

| profile | segments | sweep (s, best of 3) | segments/s | certified clearance (mm) | exact-distance configurations | swept hull pieces |
|---|---:|---:|---:|---|---:|---:|
{rows_in}

The clearance is the tip over the plate on the first layer, less the sag of the twin's joint
interpolation along long first-layer moves (the twin interpolates joints linearly between targets).

## A million moves: certified against version 1's sampled sweep

A raster of {big['moves']:,} moves ({big['rows']:,} program rows, {big['beads']:,} beads; planned in
{big['plan_s']:.1f} s), both sweeps in this process one after the other.

| sweep | time (s) | what it checks | verdict |
|---|---:|---|---|
| certified (this) | **{big['certified_s']:.1f}** ({big['certified_segments_per_s']:,.0f} segments/s) | every segment, every body, {big['beads']:,} beads; {big['certified_configs']:,} exact-distance configurations, {big['certified_pieces']:,} swept pieces | {'collision-free' if big['certified_free'] else 'HIT'}, certified clearance {big['certified_clearance_mm']:.3f} mm ({big['certified_clearance_body']}) |
| sampled (version 1) | {big['sampled_s']:.1f} | {big['sampled_configs']:,} configurations, 2 degrees of joint travel apart, one box per layer | {'collision-free' if big['sampled_free'] else 'HIT'} (clearance at the samples: {big['sampled_min_distance_mm']:.1f} mm, not a bound) |

Certified / sampled time: **{1 / big['speedup']:.2f}x** (the certified sweep is {big['speedup']:.1f}x faster).
Peak resident memory of the benchmark process: {big['peak_rss_mb']:,.0f} MB.

Multi-axis programs (curved layers, a tilted nozzle) against this sample part: `tools/bench/collision_curved_bench.py`,
[collision_curved.md](collision_curved.md).
"""
    (out / "collision.md").write_text(md)


if __name__ == "__main__":
    main(sys.argv[1:])
