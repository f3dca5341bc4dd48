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
            summary = json.loads(r.stdout)["summary"]
            runs.append({"wall_s": wall, "peak_mb": peak, "peak_anon_mb": peak_anon, "idle_mb": idle["VmRSS"],
                         "idle_anon_mb": idle.get("RssAnon", float("nan")), "csv_bytes": csv_bytes,
                         "moves": summary["moves"], "targets": summary["targets"]})
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
    (docs / "memory.json").write_text(json.dumps(r, indent=1, default=float) + "\n")
    one = r["one"]
    runs = one["runs"]
    peaks = [x["peak_mb"] for x in runs]
    idles = [x["idle_mb"] for x in runs]
    growth = (idles[-1] - idles[0]) / idles[0] if idles else float("nan")
    rows = "\n".join(f"| {i + 1} | {x['wall_s']:.1f} s | {x['peak_mb']:.0f} MB | {x['idle_mb']:.0f} MB |"
                     for i, x in enumerate(runs))
    ok = lambda c: "met" if c else "NOT met"          # noqa: E731
    md = f"""# Memory benchmark

Generated by `tools/bench/memory_bench.py` ({r['machine']['cpus']} CPUs shared with other work, load
{r['machine']['load_before'][0]:.1f} before, Python {r['machine']['python']}, numpy {r['machine']['numpy']}).
Raw figures: `memory.json`. The planner runs as its own process behind a hub, as `fabric-cli up`
starts it; each plan is the user's command as a fresh process, `fabric-cli plan FILE --csv OUT`
(upload, plan, CSV streamed back to disk). **Peak** is the planner process's highest resident size
during the command (the kernel's `VmHWM`, reset before each command, and a 5 ms sampler); **idle** its
resident size {IDLE_WAIT_S:g} s after the command returned. Before the first plan the planner holds
{one['start_mb']:.0f} MB.

## {runs[0]['moves']:,} moves ({one['file_mb']:.1f} MB of G-code), {len(runs)} plans in a row

| plan | command | peak | idle after |
|---|---|---|---|
{rows}

Peak {max(peaks):.0f} MB (goal < {GOAL_1M_PEAK_MB:.0f} MB: {ok(max(peaks) < GOAL_1M_PEAK_MB)}); idle after the
last plan {growth:+.1%} against after the first (goal within {GOAL_GROWTH_R:.0%}:
{ok(abs(growth) <= GOAL_GROWTH_R)}).
"""
    if "big" in r:
        b = r["big"]
        x = b["runs"][0]
        md += f"""
## A {b['file_mb']:.0f} MB G-code file ({x['moves']:,} moves)

| command | peak | idle after | CSV written |
|---|---|---|---|
| {x['wall_s']:.1f} s | {x['peak_mb']:.0f} MB | {x['idle_mb']:.0f} MB | {x['csv_bytes'] / 1e9:.2f} GB |

Peak {x['peak_mb']:.0f} MB (goal < {GOAL_BIG_PEAK_MB:.0f} MB: {ok(x['peak_mb'] < GOAL_BIG_PEAK_MB)}).
"""
    (docs / "memory.md").write_text(md)


if __name__ == "__main__":
    res = main(sys.argv)
    print(json.dumps({k: v for k, v in res.items() if k != "machine"}, indent=1, default=float)[:4000])
