"""Recovery benchmark: how long a killed station takes to print again, and what checkpoints cost.

Run: ``.venv/bin/python tools/bench/recovery_bench.py [--kills 5] [--pairs 3] [--out docs/bench]``.

The sample part is sliced and planned in this process and served from an
in-process planner; a collision service runs in this process too. The station
runs as its own process under the launcher's supervision (``CellProcesses``,
restart after a 0.5 s pause), as ``fabric-cli up`` runs it. Measured:

* **recovery**: ``kill -9`` of the station mid-print (seeded instants) to the
  ``recovered`` event of the print going on, split into kill -> station alive
  again (restart pause, process start, restore from the checkpoint) and alive
  -> ``recover`` answered -> ``recovered`` (a collision-checked move back);
* **checkpoint cost**: the station printing the part at max speed (rtf 0) with
  its default checkpoints (every second and after every command) against the
  named baseline, the same station with periodic checkpoints off
  (``--checkpoint-s 1e9``), A B A B in one run; the figure is simulated
  seconds per wall second and the ratio of the two (goal: at most 5 % slower).

Writes ``recovery.md`` and ``recovery.json`` under ``--out``.
"""
from __future__ import annotations

import argparse
import json
import platform
import random
import signal
import socket
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

from fabric import schemas as s
from fabric.cli.up import CellProcesses, hub_settings
from fabric.client import Client
from fabric.demo import sample_model
from fabric.planning import PlanOptions, plan_gcode
from fabric.programs import program_artifact
from fabric.robot.cell import Cell
from fabric.services.collision import CollisionService
from fabric.services.planner import PlannerService
from fabric.sim.twin import Twin
from fabric.slicing import load_profile, slice_model
from fabric.store.artifacts import ArtifactStore
from fabric.store.journal import StationJournal, StationMeta
from fabric.store.station import StationStore
from fabric.wire.config import SessionSettings, zenoh_config


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_kind(sub, kinds: tuple[str, ...], timeout_s: float = 300.0):
    end = time.monotonic() + timeout_s
    while True:
        ev = sub.get(timeout=max(0.01, end - time.monotonic()))
        if ev.kind in kinds:
            return ev


class Station:
    """The station process of one run, supervised (restarted after a pause) like ``fabric-cli up`` does."""

    def __init__(self, settings: SessionSettings, data: Path, checkpoint_s: float) -> None:
        self.cell = CellProcesses(settings, ("station",), host_hub=False, data_dir=data,
                                  extra_args={"station": ["--checkpoint-s", str(checkpoint_s), "--log-level",
                                                          "WARNING"]})
        self._stop = threading.Event()

    def __enter__(self) -> Station:
        self.cell.start(deadline_s=90.0)
        self._thread = threading.Thread(target=self._supervise, daemon=True)
        self._thread.start()
        return self

    def _supervise(self) -> None:
        while not self._stop.wait(0.02):
            self.cell.supervise(lambda line: None)

    def kill(self) -> None:
        self.cell.procs["station"].send_signal(signal.SIGKILL)

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self.cell.stop()


def print_speed(client: Client, pid: str) -> float:
    """Simulated seconds per wall second of one print at max speed (started -> finished)."""
    client.load(pid)
    events = client.subscribe("station", "events")
    try:
        client.start(rtf=0.0)
        started = wait_kind(events, ("started",))
        t0 = time.perf_counter()
        end = wait_kind(events, ("finished", "fault"))
        wall = time.perf_counter() - t0
    finally:
        events.close()
    return (end.t_sim_s - started.t_sim_s) / wall


def checkpoint_cost(settings: SessionSettings, tmp: Path, pid: str, pairs: int) -> dict:
    speeds: dict[str, list[float]] = {"default": [], "periodic off": []}
    modes = {"default": 1.0, "periodic off": 1e9}
    with Client.connect(settings) as client:
        for k in range(pairs):
            for name, period in modes.items():
                with Station(settings, tmp / f"cost-{name.replace(' ', '-')}-{k}", period):
                    client.wait_alive(("station",), deadline_s=60)
                    speeds[name].append(print_speed(client, pid))
    ratios = [a / b for a, b in zip(speeds["default"], speeds["periodic off"], strict=True)]
    return {"speeds": speeds, "ratios": ratios, "median_ratio": statistics.median(ratios)}


def journal_costs(cell: Cell, program, tmp: Path, step_s: float = 5.0) -> dict:
    """The journal's own cost, in process: a checkpoint and a tick record at points through the sample
    print, against the simulated time the station advances in the same wall time. A checkpoint at the
    default cadence costs ``checkpoint_ms / 1000`` of the station's time; a tick record ``tick_ms / 20``."""
    store = StationStore(tmp / "costs.sqlite")
    journal = StationJournal(store, ArtifactStore(tmp / "costs-artifacts"), 1.0)
    twin = Twin(cell)
    twin.load(program)
    twin.start()
    meta = StationMeta(program_id="bench", planned_mm3=program.deposited_volume_mm3())
    ck_ms, tick_ms = [], []
    while twin.state == "printing":
        events = twin.advance(step_s)
        msgs = [s.Event(seq=e.seq, t_sim_s=e.t_sim_s, kind=e.kind, row=e.row, gcode_line=e.gcode_line,
                        layer=e.layer, data=dict(e.data)) for e in events]
        t0 = time.perf_counter()
        journal.record_tick(msgs, twin.t_sim_s)
        tick_ms.append((time.perf_counter() - t0) * 1e3)
        t0 = time.perf_counter()
        journal.checkpoint(twin, meta, force=True)
        ck_ms.append((time.perf_counter() - t0) * 1e3)
    store.close()
    ck, tk = sorted(ck_ms), sorted(tick_ms)
    return {"checkpoints": len(ck), "checkpoint_ms": {"median": statistics.median(ck), "max": ck[-1]},
            "tick_ms": {"median": statistics.median(tk), "max": tk[-1]},
            "overhead_at_1s_cadence_r": statistics.median(ck) / 1000.0,
            "tick_overhead_r": statistics.median(tk) / 20.0}


def recovery(settings: SessionSettings, tmp: Path, pid: str, kills: int, seed: int) -> dict:
    rng = random.Random(seed)
    runs = []
    with Client.connect(settings) as client:
        for k in range(kills):
            with Station(settings, tmp / f"kill-{k}", 1.0) as station:
                client.wait_alive(("station",), deadline_s=60)
                client.load(pid)
                events = client.subscribe("station", "events")
                try:
                    client.start(rtf=20.0)
                    wait_kind(events, ("layer",))
                    time.sleep(rng.uniform(0.2, 2.0))
                    t_kill = time.perf_counter()
                    station.kill()
                    while client.alive(timeout=0.2)["station"]:
                        pass
                    client.wait_alive(("station",), deadline_s=60)
                    t_alive = time.perf_counter()
                    assert client.state().state == "interrupted"
                    client.recover(rtf=0.0)
                    t_ack = time.perf_counter()
                    wait_kind(events, ("recovered",))
                    t_back = time.perf_counter()
                    end = wait_kind(events, ("finished", "fault"))
                finally:
                    events.close()
                runs.append({"kill_to_alive_s": t_alive - t_kill, "alive_to_recover_ack_s": t_ack - t_alive,
                             "kill_to_printing_s": t_back - t_kill, "end": end.kind})
    total = sorted(r["kill_to_printing_s"] for r in runs)
    return {"runs": runs, "kill_to_printing_s": {"min": total[0], "median": statistics.median(total),
                                                  "max": total[-1]}}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--kills", type=int, default=5)
    p.add_argument("--pairs", type=int, default=3)
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--profile", default="robot-1.2mm")
    p.add_argument("--out", type=Path, default=Path("docs/bench"))
    a = p.parse_args()
    cell = Cell.builtin("irb140")
    model = sample_model()
    program = plan_gcode(slice_model(model.read_bytes(), model.name, load_profile(a.profile)).gcode, cell,
                         PlanOptions()).program
    settings = SessionSettings(connect=[f"tcp/127.0.0.1:{free_port()}"], cell="recoverybench")
    hub = zenoh.open(zenoh_config(hub_settings(settings)))
    session = zenoh.open(zenoh_config(settings))
    planner = PlannerService(session, settings.cell, cell)
    collision = CollisionService(session, settings.cell, cell)
    pid = planner.store_artifact(program_artifact(program))
    for svc in (planner, collision):
        svc.start()
    try:
        with tempfile.TemporaryDirectory(prefix="recovery-bench-") as tmp:
            costs = journal_costs(cell, program, Path(tmp))
            rec = recovery(settings, Path(tmp), pid, a.kills, a.seed)
            cost = checkpoint_cost(settings, Path(tmp), pid, a.pairs)
    finally:
        for svc in (collision, planner):
            svc.close()
        session.close()
        hub.close()
    result = {"python": platform.python_version(), "rows": len(program), "recovery": rec, "checkpoints": cost,
              "journal_costs": costs}
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "recovery.json").write_text(json.dumps(result, indent=2))
    r = rec["kill_to_printing_s"]
    sp = cost["speeds"]
    lines = ["# Recovery benchmark: a killed station printing again, and the cost of checkpoints", "",
             f"Python {result['python']}; `tools/bench/recovery_bench.py`; the sample part ({len(program)} rows). "
             "The station runs as its own process, supervised as `fabric-cli up` does (restart after 0.5 s).", "",
             f"**Recovery** ({a.kills} seeded kill instants mid-print): kill -9 to printing again "
             f"min {r['min']:.2f} s, median {r['median']:.2f} s, max {r['max']:.2f} s.", "",
             "| run | kill -> alive again s | alive -> recover answered s | kill -> printing again s | end |",
             "|---|---|---|---|---|"]
    for k, run in enumerate(rec["runs"]):
        lines.append(f"| {k} | {run['kill_to_alive_s']:.2f} | {run['alive_to_recover_ack_s']:.3f} | "
                     f"{run['kill_to_printing_s']:.2f} | {run['end']} |")
    lines += ["", "**Checkpoint cost** (prints at max speed, A B A B): simulated seconds per wall second.", "",
              "| pair | default (every 1 s and every command) | baseline: periodic checkpoints off | ratio |",
              "|---|---|---|---|"]
    for k, (x, y, q) in enumerate(zip(sp["default"], sp["periodic off"], cost["ratios"], strict=True)):
        lines.append(f"| {k} | {x:,.0f} | {y:,.0f} | {q:.3f} |")
    ck, tk = costs["checkpoint_ms"], costs["tick_ms"]
    lines += ["", f"Median ratio default / baseline: **{cost['median_ratio']:.3f}** "
              f"({(1 - cost['median_ratio']) * 100:+.1f} % slower; goal at most 5 %). Both keep the per-tick "
              "journal (events and the clock mark), which is what makes recovery exact between checkpoints. "
              "Whole prints at max speed on a shared machine vary by more than the effect; the direct "
              "measurement below is the figure to read.", "",
              f"**The journal's own cost, in process** ({costs['checkpoints']} checkpoints through the sample "
              f"print): a checkpoint takes median {ck['median']:.2f} ms (max {ck['max']:.2f} ms), so at the default "
              f"cadence of one per second it takes **{costs['overhead_at_1s_cadence_r'] * 100:.2f} %** of the "
              f"station's time; recording a tick (its events and the clock mark) takes median {tk['median']:.3f} ms "
              f"(max {tk['max']:.2f} ms), {costs['tick_overhead_r'] * 100:.2f} % of a 20 ms tick.", ""]
    (a.out / "recovery.md").write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
