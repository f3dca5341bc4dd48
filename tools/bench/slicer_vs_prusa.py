"""Slicer benchmark (issue 22): the built-in slicer against PrusaSlicer through ``fabric-cli slice``, part by part.

Run: ``.venv/bin/python tools/bench/slicer_vs_prusa.py [--rounds 3] [--out docs/bench]``.

The parts are generated here (``fabric.slicing.samples``, manifold3d / trimesh):
a 24-tooth gear with a bore, a hollow dome on a floor, six towers on a thin
base, two pillars joined by a deck (a 20 mm bridge) and fins 0.6-1.5 mm thick
(thin walls). Each is written as an STL and sliced by the user's command,
``fabric-cli slice PART.stl -o OUT.gcode --backend builtin|prusaslicer --json``,
against a slicer service started as ``fabric-cli serve slicer`` behind an
in-process hub on a free loopback port (multicast scouting off): the same
profile (``taz-pla-medium``, skirt included), the same CLI path, the same
service. Every command is timed as a whole process (start to exit), after one
uncounted warm-up pair, in rounds that alternate which back-end goes first;
the wall-time ratio is the median of the round-by-round ratios.

Figures are read back from the G-code files by one reader for both back-ends
(``fabric.slicing.gcode_stats``): retractions, extruded volume, layers, travel
length; the bridge area is what each back-end reports (PrusaSlicer's estimated
from its bridge volume). Targets (issue 22): retractions at most 1.25x
PrusaSlicer's, extruded volume within 1.5 %, the same number of layers, wall
time no slower than PrusaSlicer's. Writes ``slicer_vs_prusa.md`` and
``slicer_vs_prusa.json`` under ``--out``.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import trimesh
import zenoh

from fabric.cli.up import hub_settings
from fabric.client import Client
from fabric.slicing import available_backends, load_profile
from fabric.slicing.gcode_stats import gcode_stats
from fabric.slicing.samples import bridge_part, dome, gear, thin_walls, to_stl_bytes, towers
from fabric.wire.config import SessionSettings, zenoh_config

PROFILE = "taz-pla-medium"
TARGET_RETRACT_R = 1.25
TARGET_VOLUME_PCT = 1.5
PARTS = {
    "gear (24 teeth, bore)": gear,
    "dome (hollow, r 20)": dome,
    "towers (6 on a base)": towers,
    "bridge (20 mm span)": bridge_part,
    "thin walls (0.6-1.5 mm)": thin_walls,
}
BACKENDS = ("builtin", "prusaslicer")


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def fabric_cli() -> list[str]:
    """The console script a user runs; the module form when it is not installed next to this interpreter."""
    script = Path(sys.executable).parent / "fabric-cli"
    return [str(script)] if script.exists() else [sys.executable, "-m", "fabric.cli.main"]


def slice_once(stl: Path, out: Path, backend: str, client_args: list[str]) -> tuple[float, dict]:
    """One whole ``fabric-cli slice`` process: (wall seconds, its JSON result)."""
    argv = [*fabric_cli(), "slice", str(stl), "-o", str(out), "--backend", backend, "--profile", PROFILE,
            "--json", *client_args]
    t0 = time.perf_counter()
    proc = subprocess.run(argv, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=900)
    wall_s = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} exited {proc.returncode}: {proc.stderr[-800:]}")
    return wall_s, json.loads(proc.stdout.strip().splitlines()[-1])


def measure(name: str, stl: Path, work: Path, rounds: int, client_args: list[str]) -> dict:
    """Warm-up pair, then ``rounds`` pairs alternating the order; figures from the last G-code of each."""
    profile = load_profile(PROFILE)
    outs = {b: work / f"{stl.stem}.{b}.gcode" for b in BACKENDS}
    for b in BACKENDS:
        slice_once(stl, outs[b], b, client_args)
    walls: dict[str, list[float]] = {b: [] for b in BACKENDS}
    reports: dict[str, dict] = {}
    for r in range(rounds):
        for b in (BACKENDS if r % 2 == 0 else BACKENDS[::-1]):
            wall, rep = slice_once(stl, outs[b], b, client_args)
            walls[b].append(wall)
            reports[b] = rep
    row: dict = {"part": name, "faces": len(trimesh.load(stl).faces)}
    for b in BACKENDS:
        st = gcode_stats(outs[b].read_text(encoding="utf-8"), profile.filament_diameter_mm)
        row[b] = {"layers": st.layers, "extruded_mm3": st.extruded_mm3, "retractions": st.retractions,
                  "travel_mm": st.travel_mm, "bridge_area_mm2": reports[b].get("bridge_area_mm2", 0.0),
                  "reported_retractions": reports[b].get("retractions"), "wall_s": walls[b],
                  "volume_by_type_mm3": st.volume_by_type_mm3}
    bi, ps = row["builtin"], row["prusaslicer"]
    row["retract_r"] = bi["retractions"] / max(ps["retractions"], 1)
    row["volume_pct"] = 100.0 * (bi["extruded_mm3"] / ps["extruded_mm3"] - 1.0)
    row["wall_r"] = statistics.median(a / b for a, b in zip(bi["wall_s"], ps["wall_s"], strict=True))
    row["met"] = {"retractions": row["retract_r"] <= TARGET_RETRACT_R,
                  "volume": abs(row["volume_pct"]) <= TARGET_VOLUME_PCT,
                  "layers": bi["layers"] == ps["layers"], "wall_time": row["wall_r"] <= 1.0}
    return row


def render(rep: dict) -> str:
    """The Markdown report."""
    lines = [
        "# Built-in slicer vs PrusaSlicer through `fabric-cli slice` (issue 22)",
        "",
        f"Generated by `tools/bench/slicer_vs_prusa.py`: {rep['rounds']} counted pairs per part after one warm-up "
        f"pair, profile `{PROFILE}` (skirt included), PrusaSlicer {rep['versions'].get('prusaslicer')}, "
        f"built-in {rep['versions'].get('builtin')}; {rep['cpus']} CPUs shared with other work (load average at "
        f"the end {', '.join(f'{x:.2f}' for x in rep['load_average'])}); Python {rep['python']}.",
        "",
        "Each figure comes from the whole user command, `fabric-cli slice PART.stl -o OUT --backend B --json`, "
        "against one slicer service (`fabric-cli serve slicer`) behind an in-process hub: the built-in slicer "
        "runs inside the service, PrusaSlicer as the process the service starts (its ini generated from the "
        "same profile: classic perimeters, gap fill, avoid crossing perimeters, retract only when crossing "
        "perimeters, no retraction just for a layer change). Retractions, volume, layers and travel are read "
        "from both G-code files by the same reader. *Wall-time ratio* is the median of the round-by-round "
        "ratios built-in / PrusaSlicer (below 1: the built-in command is faster).",
        "",
        "| part | faces | layers (built-in / PS) | retractions (built-in / PS) | retractions ratio | volume vs PS "
        "| travel m (built-in / PS) | bridge area mm² (built-in / PS) | wall s, median (built-in / PS) "
        "| wall-time ratio | targets |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in rep["rows"]:
        b, p = r["builtin"], r["prusaslicer"]
        missed = [k for k, ok in r["met"].items() if not ok]
        lines.append(
            f"| {r['part']} | {r['faces']} | {b['layers']} / {p['layers']} | {b['retractions']} / "
            f"{p['retractions']} | {r['retract_r']:.2f}x | {r['volume_pct']:+.2f} % | "
            f"{b['travel_mm'] / 1000:.2f} / {p['travel_mm'] / 1000:.2f} | {b['bridge_area_mm2']:.0f} / "
            f"{p['bridge_area_mm2']:.0f} | {statistics.median(b['wall_s']):.2f} / {statistics.median(p['wall_s']):.2f} "
            f"| {r['wall_r']:.2f} | {'all met' if not missed else 'NOT met: ' + ', '.join(missed)} |")
    all_met = all(all(r["met"].values()) for r in rep["rows"])
    lines += [
        "",
        f"Targets: retractions at most {TARGET_RETRACT_R:g}x PrusaSlicer's, volume within {TARGET_VOLUME_PCT:g} %, "
        f"the same layers, wall-time ratio at most 1. **{'Every target holds on every part.' if all_met else 'Not every target holds: see the last column.'}**",
        "",
        "PrusaSlicer's bridge area is estimated as its `Bridge infill` volume over the layer height; the "
        "built-in slicer reports the area of the bridge regions it found (over air, and internal bridges over "
        "sparse infill, as PrusaSlicer makes them). Travel is the XY length of every non-extruding move. "
        "Both slicers retract when a travel leaves the part; PrusaSlicer also retracts on travels longer than "
        "`retract_min_travel_mm` over a top or bottom surface (only its internal regions are exempt), which the "
        "built-in slicer does not (it retracts inside the part only past `retract_inside_max_mm`): that is most "
        "of the difference on the gear and the dome.",
        "",
        f"Whole benchmark: {rep['total_s']:.0f} s.",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3, help="counted pairs per part")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[2] / "docs" / "bench")
    ap.add_argument("--only", action="append", help="benchmark only parts whose name starts with this")
    a = ap.parse_args(argv)
    versions = available_backends()
    if versions.get("prusaslicer") is None:
        print("prusa-slicer is not installed: nothing to compare with", file=sys.stderr)
        return 2
    t_start = time.perf_counter()
    st = SessionSettings(connect=[f"tcp/127.0.0.1:{free_port()}"], cell="slicebench")
    client_args = replace(st, mode="client").to_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="slicer-vs-prusa-") as tmp:
        work = Path(tmp)
        hub = zenoh.open(zenoh_config(hub_settings(st)))
        service = subprocess.Popen([*fabric_cli(), "serve", "slicer", *st.to_args(), "--log-level", "WARNING",
                                    "--data-dir", str(work / "data")])
        try:
            with Client.connect(st) as client:
                client.wait_alive(("slicer",), deadline_s=60)
            for name, make in PARTS.items():
                if a.only and not any(name.startswith(o) for o in a.only):
                    continue
                stl = work / (name.split(" ")[0] + ".stl")
                stl.write_bytes(to_stl_bytes(make()))
                row = measure(name, stl, work, a.rounds, client_args)
                rows.append(row)
                b, p = row["builtin"], row["prusaslicer"]
                print(f"{name:26s} layers {b['layers']}/{p['layers']}  retractions {b['retractions']}/"
                      f"{p['retractions']} ({row['retract_r']:.2f}x)  volume {row['volume_pct']:+.2f} %  "
                      f"wall {statistics.median(b['wall_s']):.2f}/{statistics.median(p['wall_s']):.2f} s "
                      f"(ratio {row['wall_r']:.2f})", flush=True)
        finally:
            service.terminate()
            service.wait(timeout=30)
            hub.close()
    rep = {"what": "fabric-cli slice, built-in vs PrusaSlicer, issue 22 parts", "profile": PROFILE,
           "rounds": a.rounds, "versions": versions, "cpus": os.cpu_count(), "load_average": os.getloadavg(),
           "python": platform.python_version(), "total_s": time.perf_counter() - t_start, "rows": rows}
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "slicer_vs_prusa.json").write_text(json.dumps(rep, indent=2) + "\n", encoding="utf-8")
    (a.out / "slicer_vs_prusa.md").write_text(render(rep), encoding="utf-8")
    print(f"wrote {a.out / 'slicer_vs_prusa.md'} in {rep['total_s']:.0f} s")
    return 0 if all(all(r["met"].values()) for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
