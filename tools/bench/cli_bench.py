"""CLI benchmark: ``fabric-cli position`` as a whole process against ``python -c "import zenoh, msgpack, numpy"``.

Run: ``.venv/bin/python tools/bench/cli_bench.py [--runs 15] [--out docs/bench] [--also-tree DIR [--also-label L]]``.

The committed figures add the CLI as it was before it was made thin::

    git worktree add --detach /tmp/cli-before 6385a6e
    .venv/bin/python tools/bench/cli_bench.py --runs 21 --also-tree /tmp/cli-before \
        --also-label "fabric-cli position before the thin CLI (6385a6e)"

A hub runs in this process and the station as its own process (``fabric-cli
serve station``) on a free loopback port, multicast scouting off, as in
production. Each command below is then timed as a whole process (start to
exit, interpreter start-up included), after warm-up runs, interleaved
(A B C D A B C D ...) so that a drift in the machine's speed touches all alike:

* ``python -c pass``: the interpreter alone (the floor);
* the baseline ``python -c "import zenoh, msgpack, numpy"`` (the libraries a client needs);
* ``fabric-cli --help``;
* ``fabric-cli position`` against the running station (open a client session, one query, print);
* with ``--also-tree DIR``: the same ``position`` command run from another checkout of the
  project (``python -m fabric.cli.main`` with ``PYTHONPATH=DIR``), e.g. a git worktree at an
  older commit, to show the change.

Wall and CPU time come from the operating system's accounting of each finished
child (``os.wait4``). Reported: min, median and max of each; the ratio of the
medians to the baseline (target: ``position`` at most 3x); the median of the
pair-by-pair ratios. Then, in a probe process, where the time of ``position``
goes: imports, parser, session open, first link, the query, session close.
Writes ``cli.md`` and ``cli.json`` under ``--out``.
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
from dataclasses import dataclass, replace
from pathlib import Path

import zenoh

from fabric.cli.up import hub_settings
from fabric.client import Client
from fabric.wire.config import SessionSettings, zenoh_config

TARGET_RATIO = 3.0
BASELINE = "import zenoh, msgpack, numpy"

# Runs in a fresh interpreter: the steps of `fabric-cli position`, each timed (seconds since the start).
PHASE_PROBE = """
import json, sys, time
t0 = time.perf_counter()
import zenoh
from fabric.cli.main import build_parser
from fabric.client import Client, wait_connected
from fabric.wire.config import settings_from_args, zenoh_config
t1 = time.perf_counter()
args = build_parser().parse_args(sys.argv[1:])
settings = settings_from_args(args, default_mode="client")
t2 = time.perf_counter()
session = zenoh.open(zenoh_config(settings))
t3 = time.perf_counter()
wait_connected(session, 10.0)
t4 = time.perf_counter()
Client(session, settings.cell).position()
t5 = time.perf_counter()
session.close()
t6 = time.perf_counter()
print(json.dumps({"imports": t1 - t0, "parser": t2 - t1, "session_open": t3 - t2, "first_link": t4 - t3,
                  "query": t5 - t4, "session_close": t6 - t5}))
"""


@dataclass
class Command:
    """One timed command: its words, and the environment and directory it runs in (None: this process's)."""
    argv: list[str]
    env: dict[str, str] | None = None
    cwd: Path | None = None


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def fabric_cli() -> list[str]:
    """The console script a user runs; the module form when it is not installed next to this interpreter."""
    script = Path(sys.executable).parent / "fabric-cli"
    return [str(script)] if script.exists() else [sys.executable, "-m", "fabric.cli.main"]


def run_once(cmd: Command) -> dict:
    """One whole process: wall seconds (monotonic clock) and user + system CPU seconds (wait4)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd.argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env=cmd.env, cwd=cmd.cwd)
    stderr = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall_s = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    proc.stderr.close()
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd.argv)} exited {proc.returncode}: "
                           f"{stderr.decode(errors='replace')[-500:]}")
    return {"wall_s": wall_s, "cpu_s": usage.ru_utime + usage.ru_stime}


def spread(values: list[float]) -> dict:
    return {"min": min(values), "median": statistics.median(values), "max": max(values)}


def time_commands(commands: dict[str, Command], runs: int, warmup: int) -> dict:
    """Every command ``warmup`` times uncounted, then ``runs`` rounds, the commands in turn within a round."""
    for _ in range(warmup):
        for cmd in commands.values():
            run_once(cmd)
    samples: dict[str, list[dict]] = {name: [] for name in commands}
    for _ in range(runs):
        for name, cmd in commands.items():
            samples[name].append(run_once(cmd))
    return samples


def phases(client_args: list[str], runs: int) -> dict:
    """Median seconds of each step of `position`, from ``runs`` probe processes."""
    rows = []
    for _ in range(runs):
        out = subprocess.run([sys.executable, "-c", PHASE_PROBE, "position", *client_args], capture_output=True,
                             text=True, timeout=60, check=True).stdout
        rows.append(json.loads(out))
    return {step: statistics.median(r[step] for r in rows) for step in rows[0]}


def summarise(samples: dict[str, list[dict]], baseline: str) -> dict:
    base_runs = samples[baseline]
    base_median = statistics.median(r["wall_s"] for r in base_runs)
    out = {}
    for name, runs in samples.items():
        walls = [r["wall_s"] for r in runs]
        pairs = [r["wall_s"] / b["wall_s"] for r, b in zip(runs, base_runs, strict=True)]
        out[name] = {"wall_s": spread(walls), "cpu_s": spread([r["cpu_s"] for r in runs]),
                     "ratio_of_medians": statistics.median(walls) / base_median,
                     "pairwise_ratio": spread(pairs)}
    return out


def report(result: dict) -> str:
    rows = result["commands"]
    lines = ["# CLI benchmark: `fabric-cli position` as a whole process", "",
             f"Python {result['python']}; `tools/bench/cli_bench.py`; {result['runs']} counted runs of each command "
             f"after {result['warmup']} warm-up runs, interleaved; each run is a whole process (interpreter start-up "
             "included), wall time on a monotonic clock, CPU time from `wait4`. The station runs as its "
             "own process behind an in-process hub on a free loopback port (multicast scouting off).", "",
             "| command | wall ms min | median | max | CPU ms median | median / baseline median "
             "| pair-by-pair ratio median (min-max) |",
             "|---|---|---|---|---|---|---|"]
    for name, r in rows.items():
        w, p = r["wall_s"], r["pairwise_ratio"]
        lines.append(f"| {name} | {1e3 * w['min']:.0f} | {1e3 * w['median']:.0f} | {1e3 * w['max']:.0f} | "
                     f"{1e3 * r['cpu_s']['median']:.0f} | {r['ratio_of_medians']:.2f} | "
                     f"{p['median']:.2f} ({p['min']:.2f}-{p['max']:.2f}) |")
    verdict = "met" if result["position_ratio"] <= TARGET_RATIO else "NOT met"
    lines += ["", f"**`fabric-cli position` / baseline (ratio of medians): {result['position_ratio']:.2f}** "
              f"(target at most {TARGET_RATIO:g}: {verdict}); `fabric-cli --help` / baseline: "
              f"{result['help_ratio']:.2f}.", ""]
    ph = result["phases_s"]
    total = sum(ph.values())
    lines += [f"Where `position` spends its time inside the process (median of {result['runs']} probe processes, "
              "ms; interpreter start-up and exit are the rest of the whole-process time):", "",
              "| imports | parser | session open | first link | query | session close | sum |",
              "|---|---|---|---|---|---|---|",
              "| " + " | ".join(f"{1e3 * ph[k]:.1f}" for k in ph) + f" | {1e3 * total:.1f} |", "",
              "The parser is built without importing any service: `serve` imports the one service it runs, "
              "`cell` the cell model; `tests/test_cli_thin.py` asserts that `--help` and `position` load no "
              "service, twin, scipy, trimesh, pinocchio, coal, ruckig, textual or matplotlib.", ""]
    return "\n".join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=15, help="counted runs of each command")
    p.add_argument("--warmup", type=int, default=2, help="uncounted runs of each command, first")
    p.add_argument("--out", type=Path, default=Path("docs/bench"))
    p.add_argument("--also-tree", type=Path, default=None, metavar="DIR",
                   help="also time `position` from this checkout (e.g. a git worktree at an older commit)")
    p.add_argument("--also-label", default=None, help="the name of that row (default: the directory's name)")
    a = p.parse_args()

    st = SessionSettings(connect=[f"tcp/127.0.0.1:{free_port()}"], cell="clibench")
    client_args = replace(st, mode="client").to_args()
    hub = zenoh.open(zenoh_config(hub_settings(st)))
    data = tempfile.TemporaryDirectory(prefix="cli-bench-")
    station = subprocess.Popen([*fabric_cli(), "serve", "station", *st.to_args(), "--log-level", "WARNING",
                                "--data-dir", data.name])
    try:
        with Client.connect(st) as client:
            client.wait_alive(("station",), deadline_s=60)
        commands = {
            "python -c pass (interpreter alone)": Command([sys.executable, "-c", "pass"]),
            f'baseline: python -c "{BASELINE}"': Command([sys.executable, "-c", BASELINE]),
            "fabric-cli --help": Command([*fabric_cli(), "--help"]),
            "fabric-cli position": Command([*fabric_cli(), "position", *client_args]),
        }
        if a.also_tree is not None:
            # `python -m` puts the working directory first on the path: run it from the other tree.
            tree = a.also_tree.resolve()
            commands[a.also_label or f"fabric-cli position from {tree.name}"] = Command(
                [sys.executable, "-m", "fabric.cli.main", "position", *client_args],
                env=dict(os.environ, PYTHONPATH=str(tree)), cwd=tree)
        samples = time_commands(commands, a.runs, a.warmup)
        phase_s = phases(client_args, a.runs)
    finally:
        station.terminate()
        station.wait(timeout=10)
        hub.close()

    names = list(commands)
    rows = summarise(samples, names[1])
    result = {"python": platform.python_version(), "runs": a.runs, "warmup": a.warmup, "commands": rows,
              "position_ratio": rows["fabric-cli position"]["ratio_of_medians"],
              "help_ratio": rows["fabric-cli --help"]["ratio_of_medians"], "phases_s": phase_s,
              "target_ratio": TARGET_RATIO, "samples": samples}
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "cli.json").write_text(json.dumps(result, indent=2))
    text = report(result)
    (a.out / "cli.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
