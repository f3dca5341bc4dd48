"""IK benchmark of the closed-form families, per built-in 6-axis cell, against per-point DLS IK in the same run.

For each cell (irb140 and kr6r700: OPW; ur5 and ur10: UR-type):

* **round trip**: 10,000 random joint vectors within the limits -> FK ->
  ``robot.ik`` (continuity solver) -> FK; largest position and rotation error,
  share solved outside the rows flagged singular, share flagged;
* **all 8 branches**: ``arm.ik_branches_cols`` on ``n`` random reachable
  targets in blocks of 65,536 (the solver's block size): targets/s;
* **toolpath**: ``robot.ik`` on ``n`` TCP poses of a serpentine raster over the
  cell's plate (nozzle down, 200 mm up), the way the planner calls it: targets/s;
* **baseline**: ``dls_ik_warm`` of ``tools/bench/ik_baseline.py`` (per-point
  Pinocchio damped least squares, warm-started along the path) on the first
  ``n_dls`` poses of the same raster: targets/s, and the ratio.

Writes ``docs/bench/ik.md`` and ``ik.json``.

    .venv/bin/python tools/bench/ik_bench.py [n] [n_dls]
"""
from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from ik_baseline import dls_ik_warm  # noqa: E402

from fabric.robot.cell import Cell  # noqa: E402
from fabric.robot.frames import make_T  # noqa: E402
from fabric.robot.kinematics import IK_OK, IK_SINGULAR, pose_cols  # noqa: E402

CELLS = ["irb140", "kr6r700", "ur5", "ur10"]
BLOCK = 65536


def raster(cell: Cell, n: int) -> np.ndarray:
    """n TCP poses along a serpentine raster over the cell's plate, nozzle down, layers 0.2 mm apart."""
    side = max(2, int(np.sqrt(n)))
    t = np.arange(n)
    row, col = t // side, t % side
    col = np.where(row % 2 == 0, col, side - 1 - col)
    sx, sy, _ = cell.plate_size_mm
    local = np.stack([sx * col / (side - 1), sy * (row % side) / (side - 1), 1.0 + 0.2 * (row // side)], axis=1)
    W = cell.wobj_T()
    R = np.array([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])
    return make_T(np.broadcast_to(R, (n, 3, 3)), local @ W[:3, :3].T + W[:3, 3])


def bench_cell(name: str, n: int, n_dls: int) -> dict[str, object]:
    cell = Cell.builtin(name)
    r = cell.robot
    cf = r.closed_form
    assert cf is not None
    rng = np.random.default_rng(7)
    # round trip
    q = rng.uniform(r.lower_rad, r.upper_rad, (10_000, 6))
    T = r.fk(q)
    qs, st = r.ik(T, q[0])
    back = r.fk(qs)
    pos = np.linalg.norm(back[:, :3, 3] - T[:, :3, 3], axis=1)
    f = np.sqrt(np.sum((back[:, :3, :3] - T[:, :3, :3]) ** 2, axis=(1, 2)))
    rot = 2.0 * np.arcsin(np.minimum(1.0, f / (2.0 * np.sqrt(2.0))))
    sing = st == IK_SINGULAR
    # all 8 branches on random reachable targets
    C = pose_cols(r.fk_flange(rng.uniform(r.lower_rad, r.upper_rad, (n, 6))), np.linalg.inv(cf.arm.flange_T))
    blocks = [np.ascontiguousarray(C[:, i:i + BLOCK]) for i in range(0, n, BLOCK)]
    t0 = time.perf_counter()
    for b in blocks:
        cf.arm.ik_branches_cols(b)
    dt_all = time.perf_counter() - t0
    # the toolpath, through the solver the planner uses
    P = raster(cell, n)
    t0 = time.perf_counter()
    _qp, stp = r.ik(P, cell.home_q_rad)
    dt_path = time.perf_counter() - t0
    # the baseline on the same poses
    t0 = time.perf_counter()
    _qd, okd = dls_ik_warm(r, P[:n_dls], _qp[0])
    dt_dls = time.perf_counter() - t0
    return {
        "cell": name, "family": r.ik_family, "parameters": r.family_choice.parameters(),
        "roundtrip_n": len(q), "roundtrip_pos_max_mm": float(pos.max()), "roundtrip_rot_max_rad": float(rot.max()),
        "roundtrip_ok_outside_singular_r": float(np.mean(st[~sing] == IK_OK)),
        "roundtrip_singular_r": float(sing.mean()),
        "branches8_targets_s": n / dt_all, "path_targets_s": n / dt_path, "path_ok_r": float(np.mean(stp == IK_OK)),
        "dls_targets_s": n_dls / dt_dls, "dls_converged_r": float(okd.mean()),
        "path_vs_dls_x": (n / dt_path) / (n_dls / dt_dls), "n": n, "n_dls": n_dls,
    }


def report(rows: list[dict[str, object]], meta: dict[str, object]) -> str:
    lines = [
        "# IK benchmark: closed-form families against per-point DLS IK",
        "",
        f"`.venv/bin/python tools/bench/ik_bench.py {meta['n']} {meta['n_dls']}` on {meta['machine']} "
        f"({meta['cpus']} CPUs, shared with other work: read the ratios, not the absolute rates).",
        "",
        "* **round trip**: 10,000 random joint vectors within the limits -> FK -> `robot.ik` -> FK "
        "(issue 20's bounds: 1e-6 m, 1e-6 rad; 100 % outside the rows flagged singular);",
        "* **8 branches**: every branch of every target (`arm.ik_branches_cols`, blocks of 65,536);",
        "* **toolpath**: `robot.ik` (branch tracking with continuity, limits, multi-turn joints) on a serpentine "
        "raster over the cell's plate, nozzle down, as the planner calls it;",
        "* **DLS**: per-point Pinocchio damped least squares warm-started along the same raster "
        "(`tools/bench/ik_baseline.py`), same run.",
        "",
        "| cell | family | round trip: max pos (mm) | max rot (rad) | solved outside singular | flagged singular "
        "| 8 branches (targets/s) | toolpath (targets/s) | DLS (targets/s) | toolpath / DLS |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['cell']} | {r['family']} | {r['roundtrip_pos_max_mm']:.1e} | {r['roundtrip_rot_max_rad']:.1e} "
            f"| {100 * float(r['roundtrip_ok_outside_singular_r']):.2f} % "    # type: ignore[arg-type]
            f"| {100 * float(r['roundtrip_singular_r']):.2f} % "              # type: ignore[arg-type]
            f"| {r['branches8_targets_s']:,.0f} | {r['path_targets_s']:,.0f} | {r['dls_targets_s']:,.0f} "
            f"| {r['path_vs_dls_x']:,.0f}x |")
    lines += ["", "Detected parameters (mm, deg; `theta = sign * q + offset`):", ""]
    for r in rows:
        lines.append(f"* {r['cell']} ({r['family']}): " + ", ".join(
            f"{k} {v:g}" for k, v in r["parameters"].items()))    # type: ignore[attr-defined]
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> None:
    n = int(argv[1]) if len(argv) > 1 else 1_000_000
    n_dls = int(argv[2]) if len(argv) > 2 else 2000
    rows = []
    for name in CELLS:
        rows.append(bench_cell(name, n, n_dls))
        print(json.dumps({k: v for k, v in rows[-1].items() if k != "parameters"}), flush=True)
    meta = {"n": n, "n_dls": n_dls, "machine": platform.machine(), "cpus": os.cpu_count(),
            "python": platform.python_version(), "numpy": np.__version__}
    out = ROOT / "docs" / "bench"
    (out / "ik.json").write_text(json.dumps({"meta": meta, "cells": rows}, indent=2))
    (out / "ik.md").write_text(report(rows, meta))


if __name__ == "__main__":
    main(sys.argv)
