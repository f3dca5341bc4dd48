"""Fault injection, the long version: kill -9 of each service at many seeded instants of a job.

Run: ``.venv/bin/python tools/bench/fault_bench.py [--instants 20] [--services station supervisor planner
slicer] [--out docs/bench]``.

For every service and every instant, the sample part is submitted to a cell whose services run as
processes supervised as ``fabric-cli up`` does (restart after a pause); the service is killed with
SIGKILL a seeded random delay after the job enters the phase that service works in (slicing,
planning, printing; the supervisor at any time), the cell restarts it, an interrupted print is
recovered, and the job runs to its end. Counted: jobs lost (not finished, or not exactly once in
the job list), artifacts lost (the G-code or the program no longer served), and bead lists that
differ from an undisturbed run of the same program (count, coordinates within 1e-6 mm, volumes
within 1e-9 relative). One cell per service; its jobs follow each other (``job next`` clears the
plate between them). Writes ``faults.md`` and ``faults.json`` under ``--out``.
"""
from __future__ import annotations

import argparse
import json
import random
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))

from fabric.client import Client  # noqa: E402
from fabric.wire.errors import FabricError  # noqa: E402

from support.faults import SupervisedCell, read_csv, reference_beads, run_with_fault, same_beads  # noqa: E402
from support.loopback import make_settings  # noqa: E402

SERVICES = ("station", "supervisor", "planner", "slicer")


def one_service(service: str, instants: int, seed: int, tmp: Path) -> dict:
    rng = random.Random(f"{seed}-{service}")
    runs = []
    with SupervisedCell(make_settings(), tmp / service / "data", tmp / service / "logs") as sc:
        for k in range(instants):
            delay_s = rng.uniform(0.0, 0.6)
            t0 = time.monotonic()
            run = run_with_fault(sc, service, delay_s)
            with Client.connect(sc.settings) as client:
                want = reference_beads(client, run.program_id)
                lost_artifacts = 0
                for owner, art in (("planner", run.program_id), ("slicer", run.record.gcode_id)):
                    try:
                        client.artifact(owner, art)
                    except FabricError:
                        lost_artifacts += 1
                listed = [j.job_id for j in client.jobs().jobs].count(run.record.job_id)
                if k + 1 < instants:
                    client.job_next()                       # the plate is cleared for the next job
            beads_ok = same_beads(read_csv(run.beads_csv), want)
            runs.append({"k": k, "delay_s": delay_s, "killed_in": run.killed_in, "state": run.record.state,
                         "listed": listed, "lost_artifacts": lost_artifacts, "beads_identical": beads_ok,
                         "beads": int(len(want)), "recovery_s": run.recovery_s,
                         "wall_s": time.monotonic() - t0})
            print(f"{service:<10} {k:>2}: killed in {run.killed_in:<9} -> {run.record.state:<9} "
                  f"beads {'identical' if beads_ok else 'DIFFER'}", flush=True)
    return {"service": service, "runs": runs,
            "jobs_lost": sum(r["state"] != "finished" or r["listed"] != 1 for r in runs),
            "artifacts_lost": sum(r["lost_artifacts"] for r in runs),
            "bead_lists_differing": sum(not r["beads_identical"] for r in runs)}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--instants", type=int, default=20)
    p.add_argument("--services", nargs="+", choices=SERVICES, default=list(SERVICES))
    p.add_argument("--seed", type=int, default=2026)
    p.add_argument("--out", type=Path, default=Path("docs/bench"))
    a = p.parse_args()
    results = []
    with tempfile.TemporaryDirectory(prefix="fault-bench-") as tmp:
        for service in a.services:
            results.append(one_service(service, a.instants, a.seed, Path(tmp)))
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "faults.json").write_text(json.dumps({"instants": a.instants, "seed": a.seed, "results": results},
                                                  indent=2))
    lines = ["# Fault injection: kill -9 of each service at seeded random instants of a job", "",
             f"`tools/bench/fault_bench.py --instants {a.instants} --seed {a.seed}`: the sample part, one cell "
             "per service supervised as `fabric-cli up` does; an interrupted print is recovered with "
             "`recover`. A job counts as lost unless it finished and is listed exactly once.", "",
             "| service killed | kills | killed while (count) | jobs lost | artifacts lost | bead lists differing "
             "| recovery s (median, station) |", "|---|---|---|---|---|---|---|"]
    for r in results:
        phases: dict[str, int] = {}
        for run in r["runs"]:
            phases[run["killed_in"]] = phases.get(run["killed_in"], 0) + 1
        rec = sorted(x["recovery_s"] for x in r["runs"] if x["recovery_s"] is not None)
        med = f"{rec[len(rec) // 2]:.2f}" if rec else "-"
        lines.append(f"| {r['service']} | {len(r['runs'])} | "
                     f"{', '.join(f'{k} ({v})' for k, v in sorted(phases.items()))} | {r['jobs_lost']} | "
                     f"{r['artifacts_lost']} | {r['bead_lists_differing']} | {med} |")
    lines += ["", "Bead lists are compared with an undisturbed run of the same program: same count, "
              "coordinates within 1e-6 mm, volumes within 1e-9 relative.", ""]
    (a.out / "faults.md").write_text("\n".join(lines))
    print("\n".join(lines))
    return 0 if all(r["jobs_lost"] == r["artifacts_lost"] == r["bead_lists_differing"] == 0 for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
