"""Curved layers from STL to a checked print, per shape, planar beside curved, through the user's path.

For each shape of ``fabric/slicing/curved/shapes.py`` (the first four: dome, inverted frustum with 55 deg walls,
arch, wing; and ``OTHER_SHAPES``: hook, flared vase, skewed bridge) and each bundled sample, the cell
``irb140-multiaxis`` runs as the five service processes ``fabric-cli up --cell-config irb140-multiaxis``
starts, and as whole ``fabric-cli`` processes:

* ``fabric-cli slice SHAPE.stl --layers curved|planar --json``: the slice's figures (overhang against
  planar, thickness, tilt, neighbouring axes, cusp) and its time;
* ``fabric-cli plan SHAPE.gcode --json``: reachability of every target (unreachable ones by reason and by
  the joint at fault, the first one's why) and the planning time;
* ``fabric-cli check SHAPE.gcode --json``: plan and the certified collision check of the whole print, the
  tilted tool and arm against the part as printed;
* ``fabric-cli job submit SHAPE.stl --layers curved --start --rtf 0`` then the job record: the print on the
  twin to its end (state, deposited volume against the plan's, beads, the largest bead tilt).

Writes ``docs/bench/curved_print.md`` (:mod:`curved_print_report`) and ``curved_print.json``.

    .venv/bin/python tools/bench/curved_print_bench.py [shape ...]
"""
from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from curved_print_report import CELL, report  # noqa: E402
from plan_bench import _free_port  # noqa: E402

from fabric import schemas as s  # noqa: E402
from fabric.cli.up import CellProcesses  # noqa: E402
from fabric.client import Client  # noqa: E402
from fabric.client.follow import follow_print  # noqa: E402
from fabric.samples import samples  # noqa: E402
from fabric.slicing.curved.shapes import OTHER_SHAPES, SHAPES  # noqa: E402
from fabric.wire.config import SessionSettings  # noqa: E402

DOCS = ROOT / "docs" / "bench"


def cli(args: list[str], settings: SessionSettings, timeout: float = 1800.0) -> tuple[int, dict, float]:
    """``fabric-cli ARGS --json`` as a process: exit code, the JSON it printed, wall seconds."""
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "fabric.cli.main", *args, "--json", *settings.to_args()],
                       capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - t0
    try:
        out = json.loads(r.stdout) if r.stdout.strip() else {}
    except json.JSONDecodeError:
        out = {}
    if r.returncode not in (0, 2):
        out = {**out, "error": r.stderr.strip().splitlines()[-1] if r.stderr.strip() else f"exit {r.returncode}"}
    return r.returncode, out, wall


def shape_row(name: str, stl: Path, tmp: Path, settings: SessionSettings) -> dict[str, object]:
    row: dict[str, object] = {"shape": name}
    for layers in ("planar", "curved"):
        gcode = tmp / f"{name}-{layers}.gcode"
        _, sl, slice_s = cli(["slice", str(stl), "--layers", layers, "-o", str(gcode)], settings)
        _, planned, plan_s = cli(["plan", str(gcode)], settings)
        code, ck, check_s = cli(["check", str(gcode)], settings)
        coll = ck.get("collisions", {})
        row[layers] = {
            "slice_s": slice_s, "layers": sl.get("layers"), "extruded_mm3": sl.get("extruded_mm3"),
            "figures": sl.get("curved", {}), "plan": planned.get("summary", {}), "plan_wall_s": plan_s,
            "check_s": check_s, "check_exit": code, "error": ck.get("error"),
            "collision_free": coll.get("collision_free"), "clearance_mm": coll.get("min_distance_mm"),
            "clearance_body": coll.get("clearance_body"), "segments": coll.get("segments"),
            "first_hit": (coll.get("first_hit") or {}).get("message"), "certify_s": coll.get("elapsed_s")}
    row["print"] = print_curved(stl, settings)
    return row


def print_curved(stl: Path, settings: SessionSettings) -> dict[str, object]:
    """The user's whole path: a job with curved layers, printed on the twin as fast as it goes; the plate is
    cleared after it (the next shape prints on a clear plate)."""
    t0 = time.perf_counter()
    with Client.connect(settings) as client:
        acc = client.submit(s.JobSubmit(model=stl.read_bytes(), filename=stl.name, layers="curved", start=True,
                                        rtf=0.0))
        try:
            client.wait_print_job(acc.job_id, lambda r: r.state in ("printing", "loaded", "finished"),
                                  timeout=3600)
            end = follow_print(client, timeout_s=3600)
            rec = client.wait_print_job(acc.job_id, lambda r: False, timeout=30)
        except Exception as exc:  # noqa: BLE001 - the bench reports a failed job and goes on
            client.clear_plate()
            return {"state": "failed", "error": str(exc), "wall_s": time.perf_counter() - t0}
        tilt, total, first = np.zeros(1), 0, 0
        while True:                         # every page of the part's beads (the first are the flat base's)
            page = client.call("station", "beads", s.BeadsQuery(first=first, limit=s.pipeline.MAX_BEADS_PAGE))
            total = page.total
            if len(page.axis):
                tilt = np.r_[tilt, np.degrees(np.arccos(np.clip(page.axis[:, 2], -1.0, 1.0)))]
            first += len(page.axis)
            if not len(page.axis) or first >= total:
                break
        out = {"state": rec.state, "end": end.kind, "deposited_mm3": rec.deposited_mm3,
               "planned_mm3": rec.plan.extruded_mm3 if rec.plan else None, "beads": total,
               "max_bead_tilt_deg": float(tilt.max()), "sim_s": rec.sim_elapsed_s,
               "wall_s": time.perf_counter() - t0}
        client.clear_plate()
    return out


def models(tmp: Path) -> dict[str, Path]:
    """Every shape of the bench as an STL file: the generated ones, written to ``tmp``, then the samples."""
    out = {}
    for name, make in {**SHAPES, **OTHER_SHAPES}.items():
        out[name] = tmp / f"{name}.stl"
        out[name].write_bytes(make().export(file_type="stl"))
    for sample in samples():
        out[sample.path.stem] = sample.path
    return out


def main(argv: list[str]) -> None:
    settings = SessionSettings(connect=[f"tcp/127.0.0.1:{_free_port()}"], cell="curvedbench")
    load = f"load average {os.getloadavg()[0]:.1f} at the start"
    rows = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        stls = models(tmp)
        names = argv[1:] or list(stls)
        procs = CellProcesses(settings, log_dir=tmp / "logs", data_dir=tmp / "data",
                              extra_args={svc: ["--cell-config", CELL]
                                          for svc in ("station", "slicer", "planner", "collision")})
        procs.start(deadline_s=120.0)
        try:
            client_settings = procs.client_settings
            for name in names:
                rows.append(shape_row(name, stls[name], tmp, client_settings))
                print(json.dumps(rows[-1], default=str), flush=True)
        finally:
            procs.stop()
    meta = {"machine": platform.machine(), "cpus": os.cpu_count(), "load": load, "cell": CELL}
    (DOCS / "curved_print.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1, default=str) + "\n")
    (DOCS / "curved_print.md").write_text(report(rows, meta))


if __name__ == "__main__":
    main(sys.argv)
