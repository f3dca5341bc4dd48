"""Benchmark of the pure twin: simulated seconds per wall second, and motion timing of a million moves.

Run: ``.venv/bin/python tools/bench/twin_bench.py [--moves 1000000] [--out docs/bench]``.
Writes ``twin.md`` and ``twin.json`` to ``--out``. The Zenoh telemetry part is
added by the station service's benchmark; this one measures the twin alone:

* the sample print (a square tower with heat-up, ``fabric.motion.testprog``) run
  to the end with ``advance`` steps of 1 ms, 20 ms and one single call, with
  a telemetry read (pose, extrusion, temperatures) after every step, as the
  station service does;
* ``time_program`` on a million-move linear path (IK solved once, up front),
  and the twin running that job in one ``advance``.
"""
from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from fabric.motion.program import MOVEL, PRINT, Program
from fabric.motion.testprog import square_program
from fabric.motion.timing import StartState, time_program
from fabric.robot.cell import Cell
from fabric.robot.frames import make_T, rot_x
from fabric.sim.twin import Twin


def sample_print(cell: Cell) -> Program:
    return square_program(cell, size_mm=40.0, layers=20, layer_height_mm=0.3, speed_mm_s=40.0, bead_width_mm=0.5,
                          nozzle_c=210.0, bed_c=60.0)


def run_print(cell: Cell, prog: Program, step_s: float, telemetry: bool) -> dict[str, float]:
    twin = Twin(cell)
    est = twin.load(prog).estimate_s
    twin.start()
    steps, events = 0, 0
    t0 = time.perf_counter()
    while twin.state == "printing":
        events += len(twin.advance(step_s))
        steps += 1
        if telemetry:
            twin.pose()
            twin.extrusion()
            twin.temps()
    wall = time.perf_counter() - t0
    total = twin.time_info().total_s
    return {"step_s": step_s, "steps": steps, "events": events, "simulated_s": total, "wall_s": wall,
            "sim_per_wall": total / wall, "estimate_error_rel": abs(total - est) / est,
            "extruded_mm3": twin.extrusion().extruded_mm3, "beads": len(twin.beads)}


def spiral_program(cell: Cell, n: int) -> Program:
    """``n`` extruding linear moves on an Archimedean spiral over the plate, 0.3 mm layers."""
    k = np.arange(n)
    turns = max(n / 2000.0, 1.0)
    theta = 2 * np.pi * turns * k / n * 40
    r = 20.0 + 90.0 * ((k / n * 40) % 1.0)
    xyz = np.stack([125.0 + r * np.cos(theta), 125.0 + r * np.sin(theta), 0.3 + 0.3 * (k * 40 // n)], 1)
    p = Program.empty(n, layer_height_mm=0.3, bead_width_mm=0.5)
    p.wobj = cell.wobj_T()
    p.op[:] = MOVEL
    p.section[:] = PRINT
    p.xyz_mm[:] = xyz
    R = rot_x(np.pi)
    q, status = cell.robot.ik(p.wobj @ make_T(np.broadcast_to(R, (n, 3, 3)), xyz), cell.home_q_rad)
    if np.any((status != 0) & (status != 3)):
        raise SystemExit("spiral unreachable")
    p.q_rad[:] = q
    p.quat_wxyz[:] = [0.0, 1.0, 0.0, 0.0]
    p.speed_mm_s[:] = 60.0
    p.zone_mm[:] = 0.05
    p.flow_mm3_mm[:] = 0.13
    p.layer[:] = (k * 40 // n).astype(np.int32)
    p.gcode_line[:] = k + 1
    return p


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--moves", type=int, default=1_000_000)
    ap.add_argument("--out", default="docs/bench")
    args = ap.parse_args()
    cell = Cell.builtin("irb140")
    prog = sample_print(cell)
    t = time.perf_counter()
    est = time_program(prog, cell.robot, start_state=StartState.at_joints(cell.robot, prog.wobj, cell.home_q_rad))
    estimate_wall = time.perf_counter() - t
    runs = [run_print(cell, prog, s, True) for s in (0.001, 0.02)] + [run_print(cell, prog, 1e9, False)]

    t = time.perf_counter()
    big = spiral_program(cell, args.moves)
    ik_wall = time.perf_counter() - t
    t = time.perf_counter()
    tl = time_program(big, cell.robot)
    timing_wall = time.perf_counter() - t
    twin = Twin(cell)
    twin.load(big)
    t = time.perf_counter()
    twin.start()
    while twin.state == "printing":
        twin.advance(1e9)
    run_wall = time.perf_counter() - t
    result = {
        "machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine()},
        "sample_print": {"rows": len(prog), "estimate_s": est.total_s, "estimate_wall_s": estimate_wall, "runs": runs},
        "million": {"moves": args.moves, "ik_wall_s": ik_wall, "time_program_wall_s": timing_wall,
                    "moves_per_s": args.moves / timing_wall, "simulated_s": tl.total_s,
                    "slowed_rows": int(len(tl.slowed_rows)), "twin_run_wall_s": run_wall,
                    "twin_sim_per_wall": twin.time_info().total_s / run_wall, "beads": len(twin.beads)},
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "twin.json").write_text(json.dumps(result, indent=2))
    (out / "twin.md").write_text(report(result))
    print(report(result))


def report(r: dict) -> str:
    sp, m = r["sample_print"], r["million"]
    lines = ["# Twin benchmark (pure simulation, no network)", "",
             f"Python {r['machine']['python']}, {r['machine']['cpu']}; `tools/bench/twin_bench.py`.", "",
             f"## Sample print: square tower with heat-up ({sp['rows']} rows, {sp['estimate_s']:.1f} s simulated)", "",
             f"Estimate (`time_program`) computed in {sp['estimate_wall_s'] * 1e3:.2f} ms.", "",
             "| advance step | steps | telemetry read per step | wall s | simulated s / wall s "
             "| abs(estimate - executed) / estimate |",
             "|---|---|---|---|---|---|"]
    for run, tel in zip(sp["runs"], ("yes", "yes", "no"), strict=True):
        step = "whole job" if run["step_s"] >= 1e6 else f"{run['step_s'] * 1e3:g} ms"
        lines.append(f"| {step} | {run['steps']} | {tel} | {run['wall_s']:.4f} | {run['sim_per_wall']:,.0f} | "
                     f"{run['estimate_error_rel']:.1e} |")
    lines += ["", f"## {m['moves']:,} linear moves (spiral, 40 layers)", "",
              f"* IK for the path (closed form, vectorised; the planner's job): {m['ik_wall_s']:.2f} s",
              f"* `time_program` (look-ahead, joint caps, trapezoids): {m['time_program_wall_s']:.2f} s "
              f"= {m['moves_per_s']:,.0f} moves/s; {m['simulated_s'] / 3600:.2f} h simulated, "
              f"{m['slowed_rows']} rows slowed by joint limits",
              f"* twin running the whole job in one `advance` (beads, events): {m['twin_run_wall_s']:.2f} s "
              f"= {m['twin_sim_per_wall']:,.0f} simulated s per wall s, {m['beads']:,} beads", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
