"""Planning benchmark on every built-in cell: one G-code raster -> verified joint program + CSV, against per-point DLS.

For each cell of ``fabric/cells/`` (the IRB 140, KR 6 R700, UR5, UR10 with
their closed forms, the 7-axis Panda with the batched DLS of
``fabric/robot/batch_dls.py``) the same layered serpentine raster
(``plan_bench.write_raster``, ``n_moves`` moves, placed on that cell's plate by
its work object) is planned with :func:`fabric.planning.plan_gcode_file` (parse,
map, path IK with the free nozzle rotation and the joint-jump test,
reachability, cycle time) and written as CSV (``q1_deg .. qN_deg``), the work
``fabric-cli plan FILE --csv OUT`` asks of the planner, here in one process.
Then the user's path: ``fabric-cli plan FILE --csv OUT`` as a whole process, against a
planner process serving that cell (``--cell-config NAME``), ``n_cli`` runs, the
best compared (the first run of each cell is reported too). The baseline, in the same process, is ``dls_ik_warm`` of
``tools/bench/ik_baseline.py`` (per-point Pinocchio damped least squares,
warm-started along the path) on ``n_dls`` consecutive planned targets of the
same cell. Writes ``docs/bench/plan_cells.md`` and ``plan_cells.json``.

    .venv/bin/python tools/bench/plan_cells_bench.py [n_moves] [n_dls] [n_cli]
    .venv/bin/python tools/bench/plan_cells_bench.py --report     # the page again from plan_cells.json
    .venv/bin/python tools/bench/plan_cells_bench.py 1000000 15000 6 --cells panda,ur5   # those only, printed
                                                                     # (the page is written for every cell)
"""
from __future__ import annotations

import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from ik_baseline import dls_ik_warm  # noqa: E402
from plan_bench import _free_port, _run_cli, write_raster  # noqa: E402

from fabric.cli.up import CellProcesses  # noqa: E402
from fabric.motion.program import MOVEL  # noqa: E402
from fabric.planning import PlanOptions, plan_gcode_file  # noqa: E402
from fabric.planning.post import write_csv  # noqa: E402
from fabric.planning.post.numtext import native_rows  # noqa: E402
from fabric.robot.cell import Cell, builtin_cell_names  # noqa: E402
from fabric.robot.frames import R_from_quat, make_T  # noqa: E402
from fabric.wire.config import SessionSettings  # noqa: E402


def cli_runs(name: str, gcode: Path, tmp: Path, n_runs: int, between=lambda: None) -> list[float]:
    """Wall seconds of ``fabric-cli plan FILE --csv OUT`` (whole processes) against a planner serving ``name``;
    ``between()`` runs after each (the baseline, paired with the runs it sits between)."""
    settings = SessionSettings(connect=[f"tcp/127.0.0.1:{_free_port()}"], cell=f"pc{name}")
    cell = CellProcesses(settings, ("planner",), log_dir=tmp / f"logs-{name}", data_dir=tmp / f"data-{name}",
                         extra_args={"planner": ["--cell-config", name]})
    cell.start(deadline_s=90.0)
    args = SessionSettings(connect=settings.connect, cell=settings.cell, mode="client").to_args()
    try:
        out = []
        for _ in range(n_runs):
            out.append(_run_cli([sys.executable, "-m", "fabric.cli.main", "plan", str(gcode), "--csv",
                                 str(tmp / f"{name}-cli.csv"), *args]).wall_s)
            between()
        return out
    finally:
        cell.stop()


def bench_cell(name: str, gcode: Path, moves: int, n_dls: int, tmp: Path, n_cli: int) -> dict[str, object]:
    cell = Cell.builtin(name)
    # what checking every move's sag costs (fabric/planning/refine.py): the moves kept whole but where the joints
    # would stray 10 mm (linear_tol_mm 10), planned before the default plan (the first plan of a cell also warms
    # its caches) and after it, the best of the two
    whole_s = []

    def whole() -> None:
        t0 = time.perf_counter()
        plan_gcode_file(gcode, cell, PlanOptions(linear_tol_mm=10.0))
        whole_s.append(time.perf_counter() - t0)

    whole()
    t0 = time.perf_counter()
    res = plan_gcode_file(gcode, cell, PlanOptions())
    plan_s = time.perf_counter() - t0
    whole()
    plan_whole_s = min(whole_s)
    prog = res.program
    out = tmp / f"{name}.csv"
    t0 = time.perf_counter()
    with open(out, "w", newline="\n") as f:
        rows_written = write_csv(prog, f)
    csv_s = time.perf_counter() - t0
    header = out.open().readline().strip().split(",")
    # the per-point baseline on consecutive planned targets from the middle of the path
    motion = np.flatnonzero(prog.op == MOVEL)
    a = len(motion) // 2
    rows = motion[a:a + n_dls]
    T = prog.wobj @ make_T(R_from_quat(prog.quat_wxyz[rows]), prog.xyz_mm[rows])
    dls_runs: list[float] = []
    converged: list[float] = []

    def dls() -> None:
        t0 = time.perf_counter()
        _q, ok = dls_ik_warm(cell.robot, T, prog.q_rad[motion[a - 1]], prog.q_rad[motion[a - 2]])
        dls_runs.append(time.perf_counter() - t0)
        converged.append(float(ok.mean()))

    dls()
    st = res.stats
    cli_s = cli_runs(name, gcode, tmp, n_cli, dls) if n_cli > 0 else []
    dls_s = min(dls_runs)           # the best of the runs before and between the CLI's, as the CLI's best
    ok = np.array(converged)
    return {
        "cli_s": cli_s, "cli_moves_per_s": st.moves / min(cli_s) if cli_s else float("nan"),
        "cli_vs_dls_x": (st.moves / min(cli_s)) / (len(rows) / dls_s) if cli_s else float("nan"),
        "cli_vs_dls_pairs_x": _paired_ratios(st.moves, cli_s, len(rows), dls_runs),
        "cell": name, "ik": "closed form (" + cell.robot.ik_family + ")" if cell.robot.closed_form is not None
        else "batched DLS", "joints": cell.robot.nq, "moves": moves, "feasible_r": res.report.feasible_r,
        "plan_s": plan_s, "ik_s": st.ik_s, "plan_moves_per_s": st.moves / plan_s, "plan_whole_s": plan_whole_s,
        "split_rows": st.split_rows, "refine_s": st.refine_s,
        "csv_s": csv_s, "csv_rows": rows_written, "csv_joint_columns": sum(c.endswith("_deg") for c in header),
        "plan_and_csv_moves_per_s": st.moves / (plan_s + csv_s),
        "dls_targets": len(rows), "dls_targets_per_s": len(rows) / dls_s, "dls_converged_r": float(ok.min()),
        "dls_runs": len(dls_runs), "dls_run_s": dls_runs,
        "plan_vs_dls_x": (st.moves / plan_s) / (len(rows) / dls_s),
    }


def _paired_ratios(moves: int, cli_s: list[float], n_dls: int, dls_runs: list[float]) -> list[float]:
    """CLI / DLS of each CLI run against the baseline runs on either side of it (their mean time): the
    baseline runs once before the CLI runs and after each, so CLI run k sits between baseline runs k and
    k + 1. Their median keeps one quiet or one busy moment from deciding the figure."""
    return [(moves / c) / (n_dls / (0.5 * (dls_runs[k] + dls_runs[k + 1])))
            for k, c in enumerate(cli_s) if k + 1 < len(dls_runs)]


def _median_text(values: object) -> str:
    return f"{float(np.median(values)):,.1f}x" if isinstance(values, list) and values else "-"


def _cli_text(r: dict[str, object]) -> str:
    runs = r["cli_s"]
    return f"{runs[0]:.2f}, {min(runs):.2f}" if isinstance(runs, list) and runs else "-"


def report(rows: list[dict[str, object]], meta: dict[str, object]) -> str:
    lines = [
        "# Planning on every built-in cell against per-point DLS IK",
        "",
        f"`.venv/bin/python tools/bench/plan_cells_bench.py {meta['n_moves']} {meta['n_dls']} {meta['n_cli']}` on "
        f"{meta['machine']} ({meta['cpus']} CPUs, shared with other work: read the ratios, not the absolute rates).",
        "",
        "The same layered serpentine raster on each cell's plate, planned by `plan_gcode_file` (parse, map, "
        "path IK with the free nozzle rotation and the joint-jump test, reachability, cycle time) and written "
        "as CSV (one `qN_deg` column per joint), in one process; the baseline is per-point Pinocchio DLS "
        "warm-started along the path (`tools/bench/ik_baseline.py`) on consecutive planned targets of the "
        "same cell, run before the CLI runs and after each (the best of them, as the CLI's best: the host's load "
        "swings twofold within minutes here, and the pairing keeps that drift out of the ratio). What pairing "
        "cannot remove: a busy host slows the baseline's Python loop and the planner's numpy passes unequally, "
        "so the ratio itself moves between runs (IRB 140: 9.2x in one run, 19.8x in a later one, the same "
        "planner code; its DLS 36k then 12k targets/s). A short baseline run (3,000 targets, about 0.2 s, "
        "against the CLI's 3-4 s) is likelier to fall in a quiet moment of a host whose load comes in bursts than "
        f"the CLI's; this page's baseline runs take {meta['n_dls']:,} targets each. Two columns therefore: "
        "the best CLI run against the best baseline "
        "run (as before), and the median, over the CLI runs, of each run against the mean of the baseline runs "
        "just before and just after it (the first CLI run, a planner's first plan, included). Read one run's "
        "columns together, not two runs' rows.",
        "",
        f"C helpers: {meta.get('native', 'none')} (`fabric/native/`: the CSV rows (`numtext.c`), the G-code "
        "lexer (`gclex.c`), the path IK's branch tracking of the OPW, UR and Panda-type closed forms (`armik.c`), "
        "the nozzle frames, flange columns and quaternions (`nozzle.c`), the check of every linear move's sag "
        "(`chain.c`) and the look-ahead's cruise caps (`lookahead.c`), each where it is built; "
        "`FABRIC_NATIVE=0` runs numpy's paths, which give the same results).",
        "",
        "| cell | IK | joints | moves | reachable | plan (s) | of which IK (s) | plan (moves/s) | CSV (s) "
        "| plan + CSV (moves/s) | DLS (targets/s) | plan / DLS | `fabric-cli plan --csv` (s: first, best) "
        "| CLI / DLS (best / best) | CLI / DLS (median of pairs) | rows added splitting moves "
        "| of the plan, checking the moves (s) | plan, moves kept whole (s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['cell']} | {r['ik']} | {r['joints']} | {r['moves']:,} "
            f"| {100 * float(r['feasible_r']):.2f} % | {r['plan_s']:.2f} "          # type: ignore[arg-type]
            f"| {r['ik_s']:.2f} | {r['plan_moves_per_s']:,.0f} | {r['csv_s']:.2f} "
            f"| {r['plan_and_csv_moves_per_s']:,.0f} | {r['dls_targets_per_s']:,.0f} | {r['plan_vs_dls_x']:,.1f}x "
            f"| {_cli_text(r)} | {r['cli_vs_dls_x']:,.1f}x | {_median_text(r.get('cli_vs_dls_pairs_x'))} "
            f"| {r['split_rows']:,} | {r['refine_s']:.2f} "
            f"| {r['plan_whole_s']:.2f} |")
    lines += [
        "",
        "Every linear move is checked for how far its joints, interpolated between its two rows, would take the TCP "
        "off the straight line (`fabric/planning/refine.py`: a bound from the joint travel, then forward kinematics "
        "half-way where the bound exceeds 80 % of `linear_tol_mm`, 0.1 mm) and split where they would stray "
        "further. The last column plans the same file with `linear_tol_mm` 10 (moves kept whole): the difference "
        "is what the check costs. On this raster of 5 mm moves the bound lets most 6-axis moves through without "
        "a forward kinematics; the Panda's axes do not meet, its bound is loose and nearly every move is measured "
        "(by the TCP's position alone: the chain walked back from the TCP, in C with the bound in one pass over "
        "the rows, `fabric/native/chain.c`; numpy's path: an OPW arm's point formula, else the same walk, "
        "`fabric/robot/chain_point.py`).",
    ]
    return "\n".join(lines) + "\n"


def _native_helpers() -> str:
    """Which C helpers this run used (each, or numpy's path in its place)."""
    from fabric.gcode import native_lexer
    from fabric.motion import lookahead_native
    from fabric.robot import chain_native, native_track, nozzle_native
    used = {"CSV rows": native_rows(), "lexer": native_lexer.available(), "path IK": native_track.available(),
            "nozzle frames": nozzle_native.available(), "sag check": chain_native.available(),
            "cruise caps": lookahead_native.available()}
    return ", ".join(f"{name} in {'C' if on else 'numpy'}" for name, on in used.items())


def rewrite_report() -> None:
    """The page again from ``plan_cells.json`` (its figures as measured), after a change to its words."""
    out = ROOT / "docs" / "bench"
    data = json.loads((out / "plan_cells.json").read_text())
    (out / "plan_cells.md").write_text(report(data["cells"], data["meta"]))


def main(argv: list[str]) -> None:
    if argv[1:] == ["--report"]:
        rewrite_report()
        return
    only = None
    if "--cells" in argv:
        k = argv.index("--cells")
        only = argv[k + 1].split(",")
        argv = argv[:k] + argv[k + 2:]
    n_moves = int(argv[1]) if len(argv) > 1 else 200_000
    n_dls = int(argv[2]) if len(argv) > 2 else 3000
    n_cli = int(argv[3]) if len(argv) > 3 else 2
    rows = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        gcode = tmp / "raster.gcode"
        moves = write_raster(gcode, n_moves)
        for name in builtin_cell_names():
            if only is not None and name not in only:
                continue
            rows.append(bench_cell(name, gcode, moves, n_dls, tmp, n_cli))
            print(json.dumps(rows[-1]), flush=True)
    meta = {"n_moves": n_moves, "n_dls": n_dls, "n_cli": n_cli, "machine": platform.machine(), "cpus": os.cpu_count(),
            "python": platform.python_version(), "numpy": np.__version__,
            "native": _native_helpers()}
    if only is not None:
        return
    out = ROOT / "docs" / "bench"
    (out / "plan_cells.json").write_text(json.dumps({"meta": meta, "cells": rows}, indent=2))
    (out / "plan_cells.md").write_text(report(rows, meta))


if __name__ == "__main__":
    main(sys.argv)
