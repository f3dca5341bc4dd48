"""Memory benchmark: peak and idle resident memory of the planner *process* as a user drives it.

The planner runs as its own process behind a hub, as ``fabric-cli up`` starts it
(``CellProcesses``, planner only), and every plan is the user's command as a
fresh process: ``fabric-cli plan FILE --csv OUT`` (upload in pieces, plan job,
CSV streamed back and written to disk). A sampler thread reads the planner's
``VmRSS`` from ``/proc`` every few milliseconds and its ``VmHWM`` (the kernel's
exact peak, reset before each command through ``/proc/PID/clear_refs``), so:

* **peak** is the planner's highest resident size during a command;
* **idle** is its resident size once the command has returned and the planner
  has settled (``IDLE_WAIT_S`` later): what it keeps between plans.

Two scenarios, each against a fresh planner process:

1. the planning benchmark's file of ``n_moves`` moves (1,004,000 by default)
   planned ``repeat`` times in a row (4 by default): peak and idle after each,
   and the growth of the idle size from the first plan to the last;
2. a big G-code file of ``big_mb`` MB (500 by default; lines like a slicer's,
   ``G1 X.. Y.. E..``, about 17 M moves), generated in /tmp and deleted after.

Goals (issue 17): a 1 M-move plan peaks under 600 MB, repeated plans do not
grow the planner (within 5 %), and the 500 MB file peaks under 1.5 GB. Writes
``docs/bench/memory.md`` and ``memory.json``.

    .venv/bin/python tools/bench/memory_bench.py [n_moves] [repeat] [big_mb]    # big_mb 0: skip the big file
"""
from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from plan_bench import _free_port, write_raster  # noqa: E402

from fabric.cli.up import CellProcesses  # noqa: E402
from fabric.wire.config import SessionSettings  # noqa: E402

IDLE_WAIT_S = 3.0          # after a command, before the idle size is read
SAMPLE_S = 0.005           # RSS sampling period
GOAL_1M_PEAK_MB = 600.0
GOAL_BIG_PEAK_MB = 1500.0
GOAL_GROWTH_R = 0.05
# The planner before chunked planning (commit 50ab295), measured with this script on this machine (2026-11-25,
# load 6.2): the whole toolpath and program in memory, glibc arenas and every client's shared-memory pool kept
BEFORE = {"commit": "50ab295", "one_peak_mb": [735, 999, 1074, 1138], "one_idle_mb": [735, 999, 1074, 1138],
          "one_wall_s": [6.8, 7.2, 9.9, 6.4], "big_peak_mb": 6382, "big_idle_mb": 3503, "big_wall_s": 133.9,
          "big_moves": 17_067_984}


def _cpu(pid: int) -> dict[str, float]:
    """Minor page faults and user / system CPU seconds of a process so far (``/proc/PID/stat``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    tick = os.sysconf("SC_CLK_TCK")
    return {"minflt": float(fields[7]), "utime_s": int(fields[11]) / tick, "stime_s": int(fields[12]) / tick}


def _status(pid: int) -> dict[str, float]:
    """VmRSS, VmHWM, RssAnon and RssFile of a process, MB."""
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, rest = line.partition(":")
        if key in ("VmRSS", "VmHWM", "RssAnon", "RssFile"):
            out[key] = int(rest.split()[0]) / 1024.0
    return out


class Sampler:
    """Samples a process's resident size on a thread; ``mark()`` starts a new window (peak reset)."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.peak = 0.0
        self.peak_anon = 0.0
        self.series: list[tuple[float, float]] = []
        self._stop = threading.Event()
        self._t0 = time.perf_counter()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        last = -1.0
        while not self._stop.is_set():
            try:
                st = _status(self.pid)
            except (FileNotFoundError, ProcessLookupError):
                return
            self.peak = max(self.peak, st["VmRSS"])
            self.peak_anon = max(self.peak_anon, st.get("RssAnon", 0.0))
            t = time.perf_counter() - self._t0
            if t - last >= 0.1:
                self.series.append((round(t, 2), round(st["VmRSS"], 1)))
                last = t
            time.sleep(SAMPLE_S)

    def mark(self) -> None:
        """Start a new window: the kernel's high-water mark is reset too."""
        try:
            Path(f"/proc/{self.pid}/clear_refs").write_text("5")
        except OSError:
            pass
        self.peak = self.peak_anon = 0.0

    def window_peak(self) -> float:
        """The highest resident size since :meth:`mark` (sampled, and the kernel's own mark)."""
        return max(self.peak, _status(self.pid).get("VmHWM", 0.0))

    def close(self) -> None:
        self._stop.set()
        self._thread.join()


def write_big(path: Path, size_mb: float) -> int:
    """A layered serpentine raster of about ``size_mb`` MB, every move ``G1 X.. Y.. E..`` as slicers write
    infill; returns the move count."""
    x0, x1, y0, y1, spacing, seg = 30.0, 220.0, 30.0, 220.0, 0.45, 5.0
    n_lines = int((y1 - y0) / spacing)
    n_seg = int(round((x1 - x0) / seg))
    xs = np.linspace(x0, x1, n_seg + 1)[1:]
    e_seg = 0.0332 * (x1 - x0) / n_seg
    body = []
    for i in range(n_lines):
        y = y0 + spacing * i
        if i:
            body.append(f"G1 X{(x1 if i % 2 else x0):.3f} Y{y:.3f} E{0.0332 * spacing:.5f}\n")
        for x in (xs if i % 2 == 0 else x1 + x0 - xs):
            body.append(f"G1 X{x:.3f} Y{y:.3f} E{e_seg:.5f}\n")
    text = "".join(body).encode()
    limit = int(size_mb * 1e6)
    moves = 0
    with open(path, "wb") as f:
        f.write(b"; generated by am-fabric memory_bench (PrusaSlicer-style markers)\nM104 S210\nM140 S60\n"
                b"G28\nG21\nG90\nM83\nM190 S60\nM109 S210\nG1 Z5 F3000\n")
        k = 0
        while f.tell() + len(text) + 200 < limit:
            z = 0.2 * (k + 1)
            f.write(f";LAYER_CHANGE\n;Z:{z:.2f}\n;TYPE:Solid infill\nG1 E-0.8 F2400\nG1 Z{z:.3f} F6000\n"
                    f"G1 X{x0:.3f} Y{y0:.3f}\nG1 E0.8 F2400\nG1 F2400\n".encode())
            f.write(text)
            moves += len(body) + 2
            k += 1
        f.write(b"M104 S0\nM140 S0\n")
    return moves


def _plan_cmd(path: Path, out: Path, client_args: list[str]) -> list[str]:
    return [sys.executable, "-m", "fabric.cli.main", "plan", str(path), "--csv", str(out), "--json", *client_args]


def _run_plans(path: Path, tmp: Path, repeat: int, tag: str) -> dict:
    """Start a planner process, run the plan command ``repeat`` times, measure it; stop it."""
    settings = SessionSettings(connect=[f"tcp/127.0.0.1:{_free_port()}"], cell=f"mem{tag}")
    cell = CellProcesses(settings, ("planner",), log_dir=tmp / f"logs-{tag}", data_dir=tmp / f"data-{tag}")
    cell.start(deadline_s=120.0)
    client_args = SessionSettings(connect=settings.connect, cell=settings.cell, mode="client").to_args()
    pid = cell.procs["planner"].pid
    time.sleep(1.0)
    sampler = Sampler(pid)
    runs = []
    try:
        start = _status(pid)
        for k in range(repeat):
            out = tmp / f"out-{tag}.csv"
            sampler.mark()
            cpu0 = _cpu(pid)
            t0 = time.perf_counter()
            r = subprocess.run(_plan_cmd(path, out, client_args), capture_output=True, timeout=3600)
            wall = time.perf_counter() - t0
            if r.returncode != 0:
                raise RuntimeError(f"plan failed ({r.returncode}): {r.stderr.decode()[-2000:]}")
            peak, peak_anon = sampler.window_peak(), sampler.peak_anon
            csv_bytes = out.stat().st_size
            out.unlink()
            time.sleep(IDLE_WAIT_S)
            idle = _status(pid)
            cpu = {k: v - cpu0[k] for k, v in _cpu(pid).items()}
            summary = json.loads(r.stdout)["summary"]
            runs.append({"wall_s": wall, "peak_mb": peak, "peak_anon_mb": peak_anon, "idle_mb": idle["VmRSS"],
                         "idle_anon_mb": idle.get("RssAnon", float("nan")), "csv_bytes": csv_bytes,
                         "moves": summary["moves"], "targets": summary["targets"],
                         "planner_minor_faults": cpu["minflt"], "planner_user_s": cpu["utime_s"],
                         "planner_system_s": cpu["stime_s"]})
            print(f"  [{tag}] run {k + 1}: {wall:.1f} s, peak {peak:.0f} MB, idle {idle['VmRSS']:.0f} MB",
                  flush=True)
    finally:
        sampler.close()
        cell.stop()
    return {"start_mb": start["VmRSS"], "runs": runs, "series": sampler.series}


def main(argv: list[str]) -> dict:
    n_moves = int(argv[1]) if len(argv) > 1 else 1_000_000
    repeat = int(argv[2]) if len(argv) > 2 else 4
    big_mb = float(argv[3]) if len(argv) > 3 else 500.0
    out: dict = {"machine": {"python": platform.python_version(), "numpy": np.__version__,
                             "cpus": os.cpu_count(), "platform": platform.platform(),
                             "load_before": os.getloadavg()}}
    with tempfile.TemporaryDirectory(dir="/tmp") as tmp_s:
        tmp = Path(tmp_s)
        path = tmp / "raster.gcode"
        write_raster(path, n_moves)
        out["one"] = {"file_mb": path.stat().st_size / 1e6, **_run_plans(path, tmp, repeat, "1m")}
        path.unlink()
        if big_mb > 0:
            big = tmp / "big.gcode"
            moves = write_big(big, big_mb)
            try:
                out["big"] = {"file_mb": big.stat().st_size / 1e6, "moves_written": moves,
                              **_run_plans(big, tmp, 1, "big")}
            finally:
                big.unlink(missing_ok=True)
    out["machine"]["load_after"] = os.getloadavg()
    _write(out)
    return out


def _write(r: dict) -> None:
    docs = ROOT / "docs" / "bench"
    r["before"] = BEFORE
    (docs / "memory.json").write_text(json.dumps(r, indent=1, default=float) + "\n")
    one = r["one"]
    runs = one["runs"]
    peaks = [x["peak_mb"] for x in runs]
    idles = [x["idle_mb"] for x in runs]
    growth = (idles[-1] - idles[0]) / idles[0] if idles else float("nan")
    worst = (max(idles[1:] or idles) - idles[0]) / idles[0] if idles else float("nan")
    ok = lambda c: "met" if c else "NOT met"          # noqa: E731
    rows = "\n".join(
        f"| {i + 1} | {x['wall_s']:.1f} s | {x['planner_user_s'] + x['planner_system_s']:.1f} s, "
        f"{x['planner_minor_faults'] / 1000:.0f} k | **{x['peak_mb']:.0f} MB** | **{x['idle_mb']:.0f} MB** | "
        f"{x['peak_anon_mb']:.0f} MB | {_at(BEFORE['one_peak_mb'], i)} | {_at(BEFORE['one_idle_mb'], i)} |"
        for i, x in enumerate(runs))
    md = f"""# Memory benchmark

Generated by `tools/bench/memory_bench.py` ({r['machine']['cpus']} CPUs shared with other work: load
{r['machine']['load_before'][0]:.1f} when it started, {r['machine']['load_after'][0]:.1f} when it ended; Python
{r['machine']['python']}, numpy {r['machine']['numpy']}). Raw figures: `memory.json`.

The planner runs as its own process behind a hub, as `fabric-cli up` starts it; each plan is the user's
command as a fresh process, `fabric-cli plan FILE --csv OUT` (upload in pieces, plan job, the CSV streamed
back and written to disk). **Peak** is the planner process's highest resident size during the command (the
kernel's `VmHWM`, reset before each command, and a 5 ms sampler); **idle** its resident size {IDLE_WAIT_S:g} s
after the command returned. Resident size counts the process's mapped file pages too; "anonymous" is its heap
alone. Before the first plan the planner holds {one['start_mb']:.0f} MB. The "before" columns are this script's
figures for the planner before chunked planning (commit {BEFORE['commit']}, same machine).

## {runs[0]['moves']:,} moves ({one['file_mb']:.1f} MB of G-code), {len(runs)} plans in a row

| plan | command | planner CPU, page faults | peak | idle after | peak anonymous | before: peak | before: idle |
|---|---|---|---|---|---|---|---|
{rows}

Peak {max(peaks):.0f} MB (goal < {GOAL_1M_PEAK_MB:.0f} MB: {ok(max(peaks) < GOAL_1M_PEAK_MB)}). Idle after the
last plan {growth:+.1%} against after the first, the largest after a later plan {worst:+.1%} (goal: no growth beyond
{GOAL_GROWTH_R:.0%}, {ok(worst <= GOAL_GROWTH_R)}; before:
{(BEFORE['one_idle_mb'][-1] - BEFORE['one_idle_mb'][0]) / BEFORE['one_idle_mb'][0]:+.0%}).
"""
    if "big" in r:
        b = r["big"]
        x = b["runs"][0]
        md += f"""
## A {b['file_mb']:.0f} MB G-code file ({x['moves']:,} moves, generated in /tmp and deleted after)

| | command | planner CPU | peak | idle after | peak anonymous | CSV written |
|---|---|---|---|---|---|---|
| now | {x['wall_s']:.1f} s | {x['planner_user_s'] + x['planner_system_s']:.0f} s | **{x['peak_mb']:.0f} MB** | **{x['idle_mb']:.0f} MB** | {x['peak_anon_mb']:.0f} MB | {x['csv_bytes'] / 1e9:.2f} GB |
| before ({BEFORE['commit']}) | {BEFORE['big_wall_s']:.1f} s | | {BEFORE['big_peak_mb']:,} MB | {BEFORE['big_idle_mb']:,} MB | | |

Peak {x['peak_mb']:.0f} MB (goal < {GOAL_BIG_PEAK_MB:.0f} MB: {ok(x['peak_mb'] < GOAL_BIG_PEAK_MB)}).
"""
    md += """
## Where the memory went, and what holds it now

Measured on 1 M moves (tracemalloc and resident size per stage, then the planner process's mappings in
`/proc/PID/smaps` after each plan):

* **The whole file at once.** The planner parsed the whole G-code into a toolpath (54 bytes a move), mapped it
  into a program (168 bytes a row) with the mapping's temporaries, solved the IK in blocks but into the whole
  program, then timed the whole program in one pass (some 15 arrays of 8 bytes a row) while the program was
  hashed, written and exported: some 370 bytes a row at the peak, 6.4 GB for the 500 MB file. Now the toolpath
  comes in chunks of `ik_block_rows` (262,144) rows cut between two extruding moves
  (`fabric.gcode.ToolpathChunks`), each chunk is mapped, solved and appended to files, one per column, under the
  planner's data directory (`fabric.motion.program_file.FileSink`), and the program is mapped back read-only; the
  cycle time is computed in blocks of rows (`fabric.motion.timing.program_times`, windows wide enough that the
  look-ahead gives the whole program's times). Everything that walks the program (the cold-extrusion check, the
  artifact's hash and write, the cycle time, every export) gives the pages it has read back to the OS as it goes
  (`Program.release_pages`, `madvise(MADV_DONTNEED)`); the data stays in the page cache.
* **The plan before.** The last plan stayed in memory for its exports (program and times) and was only dropped
  when the next plan ended, so two plans were resident during a plan. Now the plan before is forgotten, and its
  files removed, when the next one starts.
* **glibc arenas.** The planner keeps freed memory while it plans (`fabric.planning.memory`: each block of rows
  reuses the pages of the one before), but the lexer, exporters and artifact writer are new threads each plan and
  got arenas of their own: each plan left 40 to 110 MB more. The planner now has one arena (set before its session
  starts any thread), and once it is idle (no plan, no export being read) it gives what it holds free back to the
  OS (`malloc_trim`), so its idle size is the same after every plan.
* **Clients' shared memory.** Zenoh gives every sending process a 16 MB shared-memory pool and the receiver
  maps it for good: every `fabric-cli plan` that uploaded its G-code left 32 MB more mapped in the planner. Clients
  now send over the socket (`fabric.wire.config`: no transport pool in client mode) and still read replies from
  the services' pools.
"""
    (docs / "memory.md").write_text(md)


def _at(values: list, i: int) -> str:
    return f"{values[i]:,} MB" if i < len(values) else ""


if __name__ == "__main__":
    res = main(sys.argv)
    print(json.dumps({k: v for k, v in res.items() if k != "machine"}, indent=1, default=float)[:4000])
