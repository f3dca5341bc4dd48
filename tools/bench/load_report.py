"""The load benchmark's report: ``load.md`` from the results ``load_bench.py`` measured (``load.json``).

Regenerate it from a saved run: ``python tools/bench/load_report.py docs/bench/load.json > docs/bench/load.md``.
"""
from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path

# the designs whose round trips are measured side by side (the keys of the results)
HUB, PEER, PAPER = ("fabric client (via hub)", "fabric peer (direct)",
                    "paper: asyncio TCP, new connection per request")
HELD = "client, reply held for the query's final (Zenoh's default consolidation)"
DATA = "client, query at data priority (batched)"


def _spread(rows: list[dict], key: str) -> str:
    values = [r[key] for r in rows]
    return f"{min(values):.2f} / {statistics.median(values):.2f} / {max(values):.2f}"


def _where_the_time_goes(one: dict) -> list[str]:
    """The round trip taken apart, from the designs measured side by side."""
    u = one["under_load"]
    hub, peer, held, data, paper = u[HUB], u[PEER], u[HELD], u[DATA], u[PAPER]
    hz = statistics.median(m["pose_hz"] for m in one["per_monitor"])
    return [
        "### Where the time goes", "",
        f"* **The hop through the hub.** The same call as a peer linked to the station directly: p50 "
        f"{peer['p50']:.2f} ms, p99 {peer['p99']:.2f} ms, against {hub['p50']:.2f} / {hub['p99']:.2f} ms through "
        f"the hub: the hub, which is also fanning pose, extrusion and events out to every monitor, costs "
        f"{hub['p50'] - peer['p50']:.2f} ms at p50 and {hub['p99'] - peer['p99']:.2f} ms at p99.",
        f"* **Waiting for the query's final message.** Zenoh's default consolidation holds a reply until the "
        f"query's final message has come back through every hop; the fabric's client takes the reply as it arrives "
        f"(`fabric.wire.qos`). Held for the final, the same call takes p50 {held['p50']:.2f} ms, p99 {held['p99']:.2f} ms.",
        f"* **Queues behind telemetry.** Commands travel at interactive priority, express; the same query at "
        f"telemetry's priority, batched, takes p50 {data['p50']:.2f} ms, p99 {data['p99']:.2f} ms.",
        f"* **CPU.** Two shared cores run {one['monitors']} monitor processes (each decoding some "
        f"{hz + statistics.median(m['extrusion_hz'] for m in one['per_monitor']):.0f} messages/s in Python), the "
        f"hub, the station and the callers: the station "
        f"publishes {hz:.0f} poses/s of the {one['pose_hz_set']:g} asked, and every design's tail is time waiting "
        f"for a core. The paper's design has one process to be scheduled per request (p50 {paper['p50']:.2f} ms), "
        "and its client sleeps once; the fabric passes three processes (client, hub, station), and in each a "
        "message is read by one Zenoh thread and written by another, and the caller's thread is woken by its "
        "Zenoh thread. The station answers `position` in Zenoh's own thread from a snapshot it keeps current (no "
        "hand-over to a worker thread, no lock).",
        f"* **Encoding**: decoding and validating the Pose reply takes {one['codec_idle']['decode']['p50']:.3f} ms "
        f"(p50, idle), encoding the request {one['codec_idle']['encode']['p50']:.3f} ms; the paper's design decodes "
        "the same payload with the same codec, so this is in both columns.", "",
        f"* **Fan-out.** Each monitor gets {statistics.median(m['extrusion_hz'] for m in one['per_monitor']):.0f} "
        f"extrusion messages per s "
        f"for {hz:.0f} poses: extrusion is published on each switch of the extruder and otherwise at 20 Hz "
        "(it was published with every pose), temperatures on a new set point and otherwise at 10 Hz.", "",
        "Measured in separate runs (this benchmark's p99 varies some 30 % from run to run), nothing of it kept:", "",
        "* timestamps in the station's reply: the station itself takes 0.02 ms at p50; the time is in the two "
        "legs, each p99 3-6 ms through the hub and 2-4 ms direct;",
        "* answering `position` from Zenoh's own cache (an advanced publisher's cache, Rust, no Python): about "
        "10 % off p99, within the noise, for a second key and access rule per cell;",
        "* more Zenoh threads in the hub (`ZENOH_RUNTIME`, 2 or 3 for sending and receiving): no change;",
        "* sessions (Linux groups CPU time by session, and here every process shares the benchmark's): with the "
        "hub, the station and the paper's server each in a session of its own, p99 ratio 1.62 against 1.98 in the "
        "same pair of runs; with the caller also apart from the monitors, 2.48. Which processes share a session "
        "moves the ratio more than anything tried in the fabric.", "",
        "What remains: the hop through the hub, and the hub's fan-out to every monitor. Dashboards can be moved "
        "to a relay (next section; open or secured fabric). On an open fabric a long-lived caller can also take "
        "the hop away with a peer session (the row above); on a secured fabric the hop stays, since access "
        "control lives in the hub.",
        ""]


def _print_under_load(one: dict, where: str) -> list[str]:
    """The monitors' figures and the round trips of every design, idle and under load."""
    lines = [f"Each monitor is plain `zenoh` + `msgpack` ({where}) subscribed to pose, extrusion and "
             f"events while the station prints the sample part ({one['print_wall_s']:.1f} s wall, "
             f"{one['events_in_print']} events).", "",
             "| per monitor (min / median / max) | value |", "|---|---|",
             f"| lost events | {_spread(one['per_monitor'], 'lost_events')} |",
             f"| pose messages per s | {_spread(one['per_monitor'], 'pose_hz')} |",
             f"| pose latency p50, ms | {_spread(one['per_monitor'], 'lat_p50_ms')} |",
             f"| pose latency p99, ms | {_spread(one['per_monitor'], 'lat_p99_ms')} |", "",
             f"`position` round trip, {one['calls']} calls of each design alternating call by call, in ms:", "",
             "| design | idle p50 | idle p99 | under load p50 | under load p99 |", "|---|---|---|---|---|"]
    for name in one["idle"]:
        i, u = one["idle"][name], one["under_load"][name]
        lines.append(f"| {name} | {i['p50']:.3f} | {i['p99']:.3f} | {u['p50']:.3f} | {u['p99']:.3f} |")
    lines += ["", f"Under load, fabric client p99 / paper design p99: **{_ratio(one):.2f}** (goal: at most 1).", ""]
    return lines


def _ratio(one: dict) -> float:
    return one["under_load"][HUB]["p99"] / one["under_load"][PAPER]["p99"]


def _relay_section(one: dict, relayed: dict) -> list[str]:
    hub, via = one["under_load"][HUB], relayed["under_load"][HUB]
    return [f"## The same print, the {relayed['monitors']} monitors on a relay", "",
            "A relay (`fabric-cli relay --listen EP --connect HUB`) is a router linked to the hub: telemetry "
            "crosses to it once and it fans out to the dashboards, so the hub carrying the commands does not.", "",
            *_print_under_load(relayed, "a client of the relay"),
            f"Through the hub, `position` under load: p50 {hub['p50']:.2f} -> {via['p50']:.2f} ms, p99 "
            f"{hub['p99']:.2f} -> {via['p99']:.2f} ms with the monitors moved to the relay; the ratio to the paper's "
            f"design, measured in the same print, {_ratio(one):.2f} -> {_ratio(relayed):.2f}.", ""]


def report(r: dict) -> str:
    one = r["one_cell"]
    lines = [f"# Load: {one['monitors']} monitors on a printing cell, command round trips against the paper's "
             "design", "",
             f"Python {r['python']}, {r['cpus']} CPUs (shared); `tools/bench/load_bench.py`; one run. The hub "
             f"(`fabric-cli router`), the station and every monitor are processes of their own.", "",
             f"## One cell, {one['monitors']} monitor processes on the hub, pose at {one['pose_hz_set']:g} Hz", "",
             *_print_under_load(one, "a client of the hub")]
    lines += _where_the_time_goes(one)
    if "one_cell_relay" in r:
        lines += _relay_section(one, r["one_cell_relay"])
    if "cells" in r:
        many = r["cells"]
        rows = [m for c in many["by_cell"].values() for m in c["per_monitor"]]
        rtts = [c["round_trip"] for c in many["by_cell"].values()]
        lines += [f"## {many['cells']} cells printing at once, {many['monitors_per_cell']} monitors each, "
                  f"pose at {many['pose_hz_set']:g} Hz", "",
                  "| per monitor (min / median / max) | value |", "|---|---|",
                  f"| lost events | {_spread(rows, 'lost_events')} |",
                  f"| pose messages per s | {_spread(rows, 'pose_hz')} |",
                  f"| pose latency p99, ms | {_spread(rows, 'lat_p99_ms')} |",
                  f"| `position` p50 per cell, ms | {_spread(rtts, 'p50')} |",
                  f"| `position` p99 per cell, ms | {_spread(rtts, 'p99')} |", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    print(report(json.loads(Path(sys.argv[1]).read_text())))
