"""Station benchmark: a full print of the sample part on the twin, over Zenoh, with telemetry on.

Run: ``.venv/bin/python tools/bench/station_bench.py [--monitors 12] [--out docs/bench]``.

The sample part is sliced (built-in slicer) and planned in this process; the
program is served from an in-process planner artifact store, and the station
runs as its own process (``fabric-cli serve station``), as in production.
``--monitors`` separate Zenoh sessions subscribe to pose, extrusion and events.
Measured in the same run:

* baseline: the pure twin (no fabric) running the same program in 20 ms
  advance steps, the station's max-speed tick, with a telemetry read per step;
* the station at ``rtf 0`` (as fast as possible): simulated seconds per wall
  second from ``start`` to the ``finished`` event, pose messages per wall second
  seen by each monitor, and lost events (gaps in ``seq``) per monitor;
* the station at ``rtf 50``, to show the real-time factor is honoured.

Writes ``station.md`` and ``station.json`` under ``--out``.
"""
from __future__ import annotations

import argparse
import json
import platform
import queue
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

from fabric.cli.up import hub_settings
from fabric.client import Client
from fabric.demo import sample_model
from fabric.planning import PlanOptions, plan_gcode
from fabric.programs import program_artifact
from fabric.robot.cell import Cell
from fabric.services.planner import PlannerService
from fabric.sim.twin import Twin
from fabric.slicing import load_profile, slice_model
from fabric.wire.config import SessionSettings, zenoh_config


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def pure_twin(cell: Cell, program, step_s: float | None) -> dict:
    """The twin alone: the whole job in one ``advance`` (step None), or in steps with a telemetry read each."""
    twin = Twin(cell)
    total = twin.load(program).estimate_s
    twin.start()
    t0 = time.perf_counter()
    while twin.state == "printing":
        twin.advance(total + 1.0 if step_s is None else step_s)
        twin.pose(), twin.extrusion(), twin.temps()
    wall = time.perf_counter() - t0
    return {"sim_s": total, "wall_s": wall, "speedup": total / wall, "step_s": step_s}


def round_trips(client: Client, session: zenoh.Session, n: int = 500) -> dict:
    """Command round trips: ``position`` through the client (encode, query the station process, decode,
    validate) against the named baseline, a bare Zenoh get on an empty in-process queryable."""
    key = f"{client.keys.prefix}/bench/echo"
    q = session.declare_queryable(key, handler=zenoh.handlers.FifoChannel(64))

    def echo() -> None:                      # served from a channel, like every service (no work in callbacks)
        for query in q:
            with query:
                query.reply(key, b"")
    threading.Thread(target=echo, daemon=True).start()
    try:
        def timed(fn) -> list[float]:
            out = []
            for _ in range(n):
                t0 = time.perf_counter()
                fn()
                out.append((time.perf_counter() - t0) * 1e3)
            return sorted(out)
        bare = timed(lambda: list(session.get(key, timeout=5.0)))
        pos = timed(client.position)
    finally:
        q.undeclare()
    pct = lambda xs, p: xs[min(len(xs) - 1, int(p * len(xs)))]  # noqa: E731
    return {"n": n, "bare_get_ms": {"p50": pct(bare, 0.5), "p99": pct(bare, 0.99)},
            "position_ms": {"p50": pct(pos, 0.5), "p99": pct(pos, 0.99)}}


def station_run(client: Client, monitors: list[Client], rtf: float, pid: str) -> dict:
    subs = [(m.subscribe("station", "pose"), m.subscribe("station", "events")) for m in monitors]
    try:
        client.clear_plate()                # the operator takes the last run's part off the plate
        info = client.load(pid)
        client_events = client.subscribe("station", "events")
        t0 = time.perf_counter()
        client.start(rtf=rtf)
        while True:
            ev = client_events.get(timeout=600)
            if ev.kind in ("finished", "fault"):
                break
        wall = time.perf_counter() - t0
        client_events.close()
        time.sleep(0.3)   # let the last messages land before counting (bench, not a test)
        rates, lost, n_events = [], [], []
        for pose_sub, ev_sub in subs:
            poses = []
            while True:
                try:
                    poses.append(pose_sub.get(timeout=0.01))
                except queue.Empty:
                    break
            seqs = []
            while True:
                try:
                    seqs.append(ev_sub.get(timeout=0.01).seq)
                except queue.Empty:
                    break
            walls = [p.wall_time_s for p in poses if p.t_sim_s > 0]
            rates.append(len(walls) / max(walls[-1] - walls[0], 1e-9) if len(walls) > 1 else 0.0)
            lost.append((seqs[-1] - seqs[0] + 1 - len(seqs)) if seqs else -1)
            n_events.append(len(seqs))
        return {"rtf": rtf, "sim_s": info.estimate_s, "wall_s": wall, "speedup": info.estimate_s / wall,
                "pose_hz_per_monitor": rates, "events_per_monitor": n_events, "lost_events_per_monitor": lost}
    finally:
        for a, b in subs:
            a.close()
            b.close()


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--monitors", type=int, default=24)
    p.add_argument("--out", type=Path, default=Path("docs/bench"))
    p.add_argument("--profile", default="robot-1.2mm")
    a = p.parse_args()
    cell = Cell.builtin("irb140")
    model = sample_model()
    sliced = slice_model(model.read_bytes(), model.name, load_profile(a.profile))
    program = plan_gcode(sliced.gcode, cell, PlanOptions()).program
    base = pure_twin(cell, program, None)
    stepped = pure_twin(cell, program, 0.02)

    st = SessionSettings(connect=[f"tcp/127.0.0.1:{free_port()}"], cell="bench")
    hub = zenoh.open(zenoh_config(hub_settings(st)))
    session = zenoh.open(zenoh_config(st))
    planner = PlannerService(session, st.cell, cell)
    pid = planner.store_artifact(program_artifact(program))
    planner.start()
    data = tempfile.TemporaryDirectory(prefix="station-bench-")      # a fresh station: nothing to restore
    proc = subprocess.Popen([sys.executable, "-m", "fabric.cli.main", "serve", "station", *st.to_args(),
                             "--log-level", "WARNING", "--data-dir", data.name])
    monitors = [Client(zenoh.open(zenoh_config(st)), st.cell) for _ in range(a.monitors)]
    try:
        client = Client(session, st.cell)
        client.wait_alive(("station", "planner"), deadline_s=60)
        rtt = round_trips(client, session)
        runs = [station_run(client, monitors, 0.0, pid), station_run(client, monitors, 50.0, pid)]
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        for m in monitors:
            m.session.close()
        planner.close()
        session.close()
        hub.close()
        data.cleanup()
    fast = runs[0]
    result = {"python": platform.python_version(), "rows": len(program), "monitors": a.monitors,
              "round_trips": rtt, "baseline_pure_twin": base, "pure_twin_20ms_steps": stepped, "station": runs,
              "ratio_station_to_pure_twin": fast["speedup"] / base["speedup"]}
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "station.json").write_text(json.dumps(result, indent=2))
    lines = ["# Station benchmark: the sample part printed on the twin over Zenoh, telemetry on", "",
             f"Python {result['python']}; `tools/bench/station_bench.py`; program of {len(program)} rows; "
             f"{a.monitors} monitor sessions subscribed to pose and events. The station runs as its own process.", "",
             "| run | simulated s | wall s | x real time | pose msgs/s per monitor (min-max) | events per monitor | lost events |",
             "|---|---|---|---|---|---|---|",
             f"| baseline: pure twin, whole job in one advance, no fabric | {base['sim_s']:.1f} | "
             f"{base['wall_s']:.3f} | {base['speedup']:,.0f} | - | - | - |",
             f"| pure twin, 20 ms simulated steps + telemetry read per step | {stepped['sim_s']:.1f} | "
             f"{stepped['wall_s']:.3f} | {stepped['speedup']:,.0f} | - | - | - |"]
    for r in runs:
        hz = r["pose_hz_per_monitor"]
        lines.append(f"| station over Zenoh, rtf {'max' if r['rtf'] == 0 else r['rtf']:} | {r['sim_s']:.1f} | "
                     f"{r['wall_s']:.3f} | {r['speedup']:,.1f} | {min(hz):.1f}-{max(hz):.1f} | "
                     f"{min(r['events_per_monitor'])} | {max(r['lost_events_per_monitor'])} |")
    lines += ["", f"Station at max speed / baseline: **{result['ratio_station_to_pure_twin']:.2f}** "
              "(what the fabric, the 50 Hz telemetry to every monitor and the wall-clock tick cost; "
              "1.0 would be free).", "",
              f"**Command round trip** ({rtt['n']} calls, from this process to the station process through "
              f"the hub): `position` p50 {rtt['position_ms']['p50']:.3f} ms, p99 {rtt['position_ms']['p99']:.3f} ms; "
              f"baseline, a bare Zenoh get on an empty queryable in this process: p50 "
              f"{rtt['bare_get_ms']['p50']:.3f} ms, p99 {rtt['bare_get_ms']['p99']:.3f} ms.", "",
              "The rtf 50 run follows the first on the same station, so the nozzle starts hot and the heat-up "
              "wait is shorter: its simulated total is smaller, and equals its own estimate at load.", ""]
    (a.out / "station.md").write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
