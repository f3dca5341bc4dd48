"""Load benchmark: 50 plain-zenoh monitor processes on a printing cell, command round trips against the paper's design.

Run: ``.venv/bin/python tools/bench/load_bench.py [--monitors 50] [--pose-hz 250] [--cells 10] [--out docs/bench]``.

One cell: the hub (``fabric-cli router``) and the station run as processes of their own; the sample part
is sliced and planned here and served from an in-process planner. ``--monitors`` separate processes,
written with plain ``zenoh`` and ``msgpack`` as a third party would, subscribe to pose, extrusion and
events while the station prints with pose at ``--pose-hz``. Each reports lost events (gaps against the
station's own event log), its pose rate and its pose latency (receipt minus the pose's ``wall_time_s``).

Under that load, in the same run and alternating call by call, the ``position`` round trip:

* through the fabric's client (encode, Zenoh query through the hub to the station, decode, validate),
  as a client of the hub (two hops) and as a peer (one hop);
* the paper's design, measured as it was built: an asyncio TCP server (its own process) answering
  ``position`` with the same payload (the station's msgpack Pose), a new connection per request, the
  reply decoded and validated by the same codec.

The same print again with the monitors connected to a relay (``fabric-cli relay``, a router linked to the
hub): the hub then carries each message across once instead of fanning it out to every monitor.

Then ``--cells`` cells print at once on one hub, each with its own station and ``--cell-monitors``
monitor processes: lost events, pose rate and latency per monitor, ``position`` round trip per cell.

Writes ``load.json`` and its report ``load.md`` (``load_report.py``) under ``--out``.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import queue
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import zenoh

from fabric import schemas as s
from fabric.client import Client
from fabric.wire import codec
from fabric.wire.config import SessionSettings, zenoh_config
from fabric.wire.qos import INTERACTIVE_QOS

sys.path.insert(0, str(Path(__file__).resolve().parent))
from load_report import DATA, HELD, HUB, PAPER, PEER, report  # a sibling script, not a package

HERE = Path(__file__).resolve()


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def pct(values: list[float], p: float) -> float:
    xs = sorted(values)
    return xs[min(len(xs) - 1, int(p * len(xs)))] if xs else float("nan")


# --- a monitor process: plain zenoh + msgpack ---------------------------------------------------------------

def monitor_main(connect: str, cell: str) -> int:
    """Subscribe to pose, extrusion and events; on a line on stdin print what was seen (JSON) and exit."""
    import threading

    import msgpack
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([connect]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    lock = threading.Lock()
    lat_ms: list[float] = []
    pose_walls: list[float] = []
    extrusion_walls: list[float] = []
    events: list[int] = []

    def on_pose(sample: zenoh.Sample) -> None:
        now = time.time()
        msg = msgpack.unpackb(sample.payload.to_bytes())
        with lock:
            lat_ms.append((now - msg["wall_time_s"]) * 1e3)
            pose_walls.append(now)

    def on_extrusion(sample: zenoh.Sample) -> None:
        now = time.time()
        with lock:
            extrusion_walls.append(now)

    def on_event(sample: zenoh.Sample) -> None:
        msg = msgpack.unpackb(sample.payload.to_bytes())
        with lock:
            events.append(msg["seq"])

    with zenoh.open(conf) as session:
        session.declare_subscriber(f"am/{cell}/station/pose", on_pose)
        session.declare_subscriber(f"am/{cell}/station/extrusion", on_extrusion)
        session.declare_subscriber(f"am/{cell}/station/events", on_event)
        print("ready", flush=True)
        sys.stdin.readline()
        with lock:
            print(json.dumps({"lat_ms": lat_ms, "pose_walls": pose_walls, "extrusion_walls": extrusion_walls,
                              "events": events}), flush=True)
    return 0


@dataclass
class Monitor:
    proc: subprocess.Popen

    @classmethod
    def start(cls, connect: str, cell: str) -> Monitor:
        return cls(subprocess.Popen([sys.executable, str(HERE), "monitor", connect, cell], stdin=subprocess.PIPE,
                                    stdout=subprocess.PIPE, text=True))

    def ready(self) -> None:
        assert self.proc.stdout.readline().strip() == "ready"

    def finish(self, print_window: tuple[float, float], expected: set[int]) -> dict:
        """Pose rate and latency while printing, events lost against the station's log."""
        self.proc.stdin.write("stop\n")
        self.proc.stdin.flush()
        seen = json.loads(self.proc.stdout.readline())
        self.proc.wait(timeout=30)
        t0, t1 = print_window
        walls = [w for w in seen["pose_walls"] if t0 <= w <= t1]
        lat = [lat for lat, w in zip(seen["lat_ms"], seen["pose_walls"], strict=True) if t0 <= w <= t1]
        ext = [w for w in seen["extrusion_walls"] if t0 <= w <= t1]
        return {"pose_hz": len(walls) / max(t1 - t0, 1e-9), "extrusion_hz": len(ext) / max(t1 - t0, 1e-9),
                "lat_p50_ms": pct(lat, 0.5),
                "lat_p99_ms": pct(lat, 0.99), "lost_events": len(expected - set(seen["events"]))}


# --- the paper's design: asyncio TCP server, a new connection per request ---------------------------------

def paper_server_main(port: int, payload_file: str) -> int:
    payload = Path(payload_file).read_bytes()

    async def answer(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        command = (await reader.readline()).strip()
        writer.write(payload if command == b"position" else b"")
        await writer.drain()
        writer.close()

    async def serve() -> None:
        server = await asyncio.start_server(answer, "127.0.0.1", port)
        print("ready", flush=True)
        async with server:
            await server.serve_forever()
    asyncio.run(serve())
    return 0


def paper_position(port: int) -> s.Pose:
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.sendall(b"position\n")
        chunks = []
        while chunk := sock.recv(65536):
            chunks.append(chunk)
    return codec.decode(b"".join(chunks), s.Pose)


def round_trips(calls: dict, n: int) -> dict:
    """``n`` calls of each, alternating call by call (same load for all), in ms."""
    times: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(n):
        for name, fn in calls.items():
            t0 = time.perf_counter()
            fn()
            times[name].append((time.perf_counter() - t0) * 1e3)
    return {name: {"p50": pct(ts, 0.5), "p99": pct(ts, 0.99), "mean": statistics.fmean(ts)}
            for name, ts in times.items()}


# --- the cell under test -------------------------------------------------------------------------------------

class Bench:
    """Hub and stations as processes; programs served from in-process planners (one per cell)."""

    def __init__(self, tmp: Path, cells: list[str], pose_hz: float) -> None:
        self.procs: list[subprocess.Popen] = []
        self.planners: list = []
        self.relay_endpoint: str | None = None
        self.session = None
        try:
            self._start(tmp, cells, pose_hz)
        except BaseException:
            self.close()                # no hub or station left behind
            raise

    def _start(self, tmp: Path, cells: list[str], pose_hz: float) -> None:
        from fabric.demo import sample_model
        from fabric.planning import PlanOptions, plan_gcode
        from fabric.programs import program_artifact
        from fabric.robot.cell import Cell
        from fabric.services.planner import PlannerService
        from fabric.slicing import load_profile, slice_model
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        hub = self._spawn("router", "--listen", self.endpoint)
        assert b"listening" in hub.stdout.readline()
        robot_cell = Cell.builtin("irb140")
        model = sample_model()
        sliced = slice_model(model.read_bytes(), model.name, load_profile("robot-1.2mm"))
        program = program_artifact(plan_gcode(sliced.gcode, robot_cell, PlanOptions()).program)
        self.settings = {c: SessionSettings(connect=[self.endpoint], cell=c) for c in cells}
        self.session = zenoh.open(zenoh_config(SessionSettings(connect=[self.endpoint])))
        for cell in cells:
            planner = PlannerService(self.session, cell, robot_cell)
            self.program_id = planner.store_artifact(program)
            planner.start()
            self.planners.append(planner)
            self._spawn("serve", "station", *self.settings[cell].to_args(), "--log-level", "WARNING",
                        "--data-dir", str(tmp / "data"), "--pose-hz", str(pose_hz))
        self.clients = {c: Client(self.session, c) for c in cells}
        for client in self.clients.values():
            client.wait_alive(("station", "planner"), deadline_s=120)

    def relay(self) -> str:
        """Start a relay linked to the hub (once); the endpoint dashboards connect to."""
        if self.relay_endpoint is None:
            self.relay_endpoint = f"tcp/127.0.0.1:{free_port()}"
            proc = self._spawn("relay", "--listen", self.relay_endpoint, "--connect", self.endpoint)
            assert b"fabric relay listening" in proc.stdout.readline()
        return self.relay_endpoint

    def _spawn(self, *args: str) -> subprocess.Popen:
        self.procs.append(subprocess.Popen([sys.executable, "-m", "fabric.cli.main", *args], stdout=subprocess.PIPE))
        return self.procs[-1]

    def close(self) -> None:
        for planner in self.planners:
            planner.close()
        if self.session is not None:
            self.session.close()
        for proc in reversed(self.procs):
            proc.terminate()
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def print_window(client: Client, rtf: float) -> tuple[int, float]:
    """Load the program and start it; returns the first event seq of the print and its start wall time."""
    first = client.events().events
    client.start(rtf=rtf)
    return (first[-1].seq + 1 if first else 0), time.time()


def wait_finished(client: Client, since_seq: int, timeout_s: float = 900.0) -> tuple[float, set[int]]:
    events = client.subscribe("station", "events")
    try:
        end = time.monotonic() + timeout_s
        while client.state().state == "printing" and time.monotonic() < end:
            try:
                events.get(timeout=1.0)
            except queue.Empty:         # ask the state again
                pass
    finally:
        events.close()
    t_end = time.time()
    log = client.events(since_seq=since_seq).events
    return t_end, {ev.seq for ev in log if ev.seq >= since_seq}


def one_cell(tmp: Path, monitors: int, pose_hz: float, calls: int, print_s: float, relay: bool = False) -> dict:
    """The print under load; with ``relay`` the monitors connect to a ``fabric-cli relay`` linked to the hub."""
    bench = Bench(tmp, ["load"], pose_hz)
    try:
        client = bench.clients["load"]
        info = client.load(bench.program_id)
        payload = tmp / "pose.msgpack"
        payload.write_bytes(codec.encode(client.position()))
        port = free_port()
        server = subprocess.Popen([sys.executable, str(HERE), "paper-server", str(port), str(payload)],
                                  stdout=subprocess.PIPE, text=True)
        bench.procs.append(server)
        assert server.stdout.readline().strip() == "ready"
        peer = Client(zenoh.open(zenoh_config(bench.settings["load"])), "load")
        with Client.connect(replace(bench.settings["load"], mode="client")) as fab:
            fab.wait_alive(("station",), deadline_s=30)
            key, empty = fab.keys.cmd("station", "position"), codec.encode(s.Empty())

            def variant(**qos) -> Callable[[], s.Pose]:     # the same query with one setting changed
                def call() -> s.Pose:
                    for reply in fab.session.get(key, payload=empty, timeout=5.0, **qos):
                        return codec.decode(reply.ok.payload.to_bytes(), s.Pose)
                return call
            designs = {HUB: fab.position, PEER: peer.position,
                       HELD: variant(**{**INTERACTIVE_QOS, "consolidation": zenoh.ConsolidationMode.AUTO}),
                       DATA: variant(**{**INTERACTIVE_QOS, "priority": zenoh.Priority.DATA, "express": False}),
                       PAPER: lambda: paper_position(port)}
            idle = round_trips(designs, calls)
            pose_bytes = payload.read_bytes()
            codec_ms = round_trips({"decode": lambda: codec.decode(pose_bytes, s.Pose),
                                    "encode": lambda: codec.encode(s.Empty())}, calls)
            mons = [Monitor.start(bench.relay() if relay else bench.endpoint, "load") for _ in range(monitors)]
            for m in mons:
                m.ready()
            since, t0 = print_window(client, rtf=info.estimate_s / print_s)
            loaded = round_trips(designs, calls)
            calls_end = time.time()
            t1, expected = wait_finished(client, since)
            if calls_end > t1:
                raise RuntimeError(f"the print ended {calls_end - t1:.1f} s before the calls under load did: "
                                   "give it more --print-s or fewer --calls")
            per_monitor = [m.finish((t0, t1), expected) for m in mons]
        peer.session.close()
        return {"monitors": monitors, "relay": relay, "pose_hz_set": pose_hz, "calls": calls,
                "print_wall_s": t1 - t0,
                "events_in_print": len(expected), "codec_idle": codec_ms, "idle": idle, "under_load": loaded,
                "per_monitor": per_monitor}
    finally:
        bench.close()


def many_cells(tmp: Path, cells: int, per_cell: int, pose_hz: float, calls: int, print_s: float) -> dict:
    names = [f"load{k}" for k in range(cells)]
    bench = Bench(tmp, names, pose_hz)
    try:
        mons = {c: [Monitor.start(bench.endpoint, c) for _ in range(per_cell)] for c in names}
        for ms in mons.values():
            for m in ms:
                m.ready()
        starts = {}
        for c in names:
            info = bench.clients[c].load(bench.program_id)
            starts[c] = print_window(bench.clients[c], rtf=info.estimate_s / print_s)
        rtt = round_trips({c: bench.clients[c].position for c in names}, calls)
        out = {}
        for c in names:
            t1, expected = wait_finished(bench.clients[c], starts[c][0])
            out[c] = {"round_trip": rtt[c], "print_wall_s": t1 - starts[c][1],
                      "per_monitor": [m.finish((starts[c][1], t1), expected) for m in mons[c]]}
        return {"cells": cells, "monitors_per_cell": per_cell, "pose_hz_set": pose_hz, "by_cell": out}
    finally:
        bench.close()


def main(argv: list[str]) -> int:
    if argv[:1] == ["monitor"]:
        return monitor_main(argv[1], argv[2])
    if argv[:1] == ["paper-server"]:
        return paper_server_main(int(argv[1]), argv[2])
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--monitors", type=int, default=50)
    p.add_argument("--pose-hz", type=float, default=250.0)
    p.add_argument("--calls", type=int, default=3000, help="round trips of each design, idle and under load")
    p.add_argument("--print-s", type=float, default=60.0, help="wall seconds the print should last")
    p.add_argument("--cells", type=int, default=10, help="cells printing at once in the second part (0: skip)")
    p.add_argument("--cell-monitors", type=int, default=3)
    p.add_argument("--cells-pose-hz", type=float, default=50.0)
    p.add_argument("--no-relay", dest="relay", action="store_false",
                   help="skip the second print, with the monitors on a relay")
    p.add_argument("--out", type=Path, default=Path("docs/bench"))
    a = p.parse_args(argv)
    result = {"python": platform.python_version(), "cpus": os.cpu_count()}
    with tempfile.TemporaryDirectory(prefix="load-bench-") as tmp:
        result["one_cell"] = one_cell(Path(tmp) / "one", a.monitors, a.pose_hz, a.calls, a.print_s)
        if a.relay:
            result["one_cell_relay"] = one_cell(Path(tmp) / "relay", a.monitors, a.pose_hz, a.calls, a.print_s,
                                                relay=True)
        if a.cells:
            result["cells"] = many_cells(Path(tmp) / "many", a.cells, a.cell_monitors, a.cells_pose_hz, 300,
                                         a.print_s)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "load.json").write_text(json.dumps(result, indent=1))
    (a.out / "load.md").write_text(report(result))
    print(report(result))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
