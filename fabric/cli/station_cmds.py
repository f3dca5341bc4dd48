"""CLI commands for the station (the paper's operator commands), status and telemetry."""
from __future__ import annotations

import argparse
import queue
from pathlib import Path

from fabric import schemas as s
from fabric.cli.output import emit
from fabric.client import Client
from fabric.wire.errors import BadRequest, FabricError
from fabric.wire.keys import SERVICES

__all__ = ["register", "NOT_READY_EXIT"]

NOT_READY_EXIT = 2          # `ready` when the station is not ready (1 is an error, as for every command)


def _pose_text(p) -> str:
    x, y, z = p.xyz_mm
    bx, by, bz = p.base_xyz_mm
    q = ", ".join(f"{v:.2f}" for v in p.q_deg)
    return (f"TCP  plate ({x:.2f}, {y:.2f}, {z:.2f}) mm   base ({bx:.2f}, {by:.2f}, {bz:.2f}) mm\n"
            f"quat (w,x,y,z) ({', '.join(f'{v:.4f}' for v in p.quat_wxyz)})\n"
            f"joints [{q}] deg   t_sim {p.t_sim_s:.2f} s")


def _time_text(t) -> str:
    return (f"elapsed {t.elapsed_s:.2f} s  total {t.total_s:.2f} s  remaining {t.remaining_s:.2f} s  "
            f"(estimate {t.estimate_s:.2f} s)  [{t.state}]")


def _ready_text(r) -> str:
    lines = [f"station {'READY' if r.ready else 'NOT READY'}"]
    lines += [f"  [{'pass' if c.ok else 'FAIL'}] {c.name}{': ' + c.detail if c.detail else ''}" for c in r.checks]
    return "\n".join(lines)


def _service_line(i) -> str:
    if not i.alive:
        return f"  {i.name:<11} DEAD"
    if i.health == "degraded":
        return f"  {i.name:<11} alive  DEGRADED: {'; '.join(i.reasons)}"
    return f"  {i.name:<11} alive  {i.health or 'health unknown'}"


def _status_text(st) -> str:
    info = st.station_cell
    head = f"cell {st.cell}" + (f": {info.name}, {len(info.joint_names)} joints ({info.ik_family} IK)" if info else "")
    lines = [head] + [_service_line(i) for i in st.services]
    if st.robot is not None:
        lines.append(st.robot.line())
    job = st.job
    if job is not None:
        lines.append(f"job {job.job_id} {job.filename}: {job.state} {job.stage}".rstrip())
    if st.job_error:
        lines.append(st.job_error if not any(i.alive for i in st.services) else f"job unknown: {st.job_error}")
    return "\n".join(lines)


def _collision_text(r) -> str:
    if r.collision_free:
        return (f"collision-free: {r.checked_configs} configurations checked, min clearance "
                f"{r.min_distance_mm:.1f} mm ({r.elapsed_s:.2f} s)")
    h = r.first_hit
    return (f"COLLISION at t={h.t_s:.2f} s, row {h.row}, G-code line {h.gcode_line}: "
            f"{h.body_a} <-> {h.body_b}")


def _ack_text(a) -> str:
    return a.message or ("ok" if a.ok else "failed")


def cmd_status(c: Client, a: argparse.Namespace) -> int:
    """Liveliness straight from the fabric (works even when the supervisor is down)."""
    if a.wait > 0:
        c.wait_alive(deadline_s=a.wait)
    alive = c.alive(timeout=a.timeout)
    healths = c.healths(timeout=min(a.timeout, 1.0)) if any(alive.values()) else {}
    st = s.FabricStatus(cell=c.keys.cell, services=[
        s.ServiceInfo(name=n, alive=v, health=healths[n].state if v and n in healths else "",
                      reasons=list(healths[n].reasons) if v and n in healths else [])
        for n, v in alive.items()])
    if alive.get("supervisor"):
        try:
            sup = c.status()                # it asks the station for its cell too
            st.job, st.station_cell, st.robot = sup.job, sup.station_cell, sup.robot
        except FabricError as exc:  # the supervisor may be mid-shutdown: liveliness already answered
            st.job_error = str(exc)
    if alive.get("station") and st.station_cell is None:
        st.station_cell = c.station_cell(timeout=a.timeout)
        st.robot = c.station_robot(timeout=a.timeout)
    if not any(alive.values()):
        cells = c.cells(timeout=a.timeout)
        others = ", ".join(cells) if cells else "none"
        st.job_error = (f"no service of cell {c.keys.cell!r} is on the fabric (cells present: {others}); "
                        "is the cell name right (--cell, $FABRIC_CELL)?")
    emit(st, a.json, _status_text)
    if not all(alive.values()):
        return 3
    return 4 if any(i.health == "degraded" for i in st.services) else 0


def cmd_cells(c: Client, a: argparse.Namespace) -> int:
    """Cells with at least one service alive, from the liveliness tokens (no service is asked)."""
    cells = c.cells(timeout=a.timeout)
    listing = [{"cell": cell, "services": services, "complete": set(services) >= set(SERVICES)}
               for cell, services in cells.items()]

    def text(rows: list[dict]) -> str:
        if not rows:
            return "no cell on the fabric"
        return "\n".join(f"{r['cell']:<16} {len(r['services'])}/{len(SERVICES)} services  {' '.join(r['services'])}"
                         for r in rows)
    emit(listing, a.json, text)
    return 0 if listing else 3


def cmd_calibrate(c: Client, a: argparse.Namespace) -> int:
    r = c.calibrate()
    emit(r, a.json, lambda r: (
        f"plate frame corrected by ({', '.join(f'{v:.3f}' for v in r.correction_xyz_mm)}) mm, "
        f"({', '.join(f'{v:.4f}' for v in r.correction_rpy_deg)}) deg; residual RMS {r.residual_rms_mm:.4f} mm "
        f"over {r.points} probes"))
    return 0


def cmd_watch(c: Client, a: argparse.Namespace) -> int:
    sub = c.subscribe("station", a.topic)
    n = 0
    try:
        while a.count <= 0 or n < a.count:
            try:
                msg = sub.get(timeout=a.timeout if a.timeout > 0 else None)
            except queue.Empty:
                break
            n += 1
            emit(msg, a.json, _watch_text(a.topic))
    except KeyboardInterrupt:
        pass
    finally:
        sub.close()
    return 0


def _watch_text(topic: str):
    if topic == "pose":
        return lambda p: (f"{p.t_sim_s:9.2f}s  xyz ({p.xyz_mm[0]:8.2f} {p.xyz_mm[1]:8.2f} {p.xyz_mm[2]:8.2f})  "
                          f"q [{' '.join(f'{v:7.2f}' for v in p.q_deg)}]")
    if topic == "extrusion":
        return lambda e: (f"{e.t_sim_s:9.2f}s  {'ON ' if e.on else 'off'} flow {e.flow_mm3_s:7.2f} mm3/s  "
                          f"total {e.extruded_mm3:10.1f} mm3  layer {e.layer + 1}  line {e.gcode_line}")
    if topic == "events":
        return lambda e: (f"#{e.seq:<6} {e.t_sim_s:9.2f}s  {e.kind:<13} layer {e.layer + 1} line {e.gcode_line} "
                          f"{e.data or ''}")
    return None


def cmd_mesh(c: Client, a: argparse.Namespace) -> int:
    art = c.mesh(a.format)
    Path(a.output).write_bytes(art.data)
    emit({"path": a.output, "bytes": len(art.data), "artifact_id": art.artifact_id}, a.json,
         lambda d: f"wrote {d['path']} ({d['bytes']} bytes)")
    return 0


def _events_text(evs: s.EventList) -> str:
    if not evs.events:
        return "no events"
    return "\n".join(f"#{e.seq:<6} {e.t_sim_s:9.2f}s  {e.kind:<12} layer {_or_dash(e.layer + 1, e.layer):<4} "
                     f"line {_or_dash(e.gcode_line, e.gcode_line):<7} {_data_text(e.data)}".rstrip()
                     for e in evs.events)


def _or_dash(shown: int, raw: int) -> str:
    """A layer or line number, or "-" when the event has none (``raw`` -1)."""
    return "-" if raw < 0 else str(shown)


def _data_text(data: dict) -> str:
    return "  ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}" for k, v in data.items())


def _layer_index(number: int | None) -> int:
    """The wire's 0-based layer index of a layer number as people count (1 = the first); -1 for none."""
    if number is None:
        return -1
    if number < 1:
        raise BadRequest(f"--layer counts from 1, got {number}", field="layer", value=number)
    return number - 1


def register(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    def simple(name: str, fn, text, help_: str, exit_code=None, **kw):
        def run(c: Client, a: argparse.Namespace) -> int:
            result = fn(c, a)
            emit(result, a.json, text)
            return exit_code(result) if exit_code is not None else 0

        p = sub.add_parser(name, parents=[common], help=help_)
        p.set_defaults(run=run, **kw)
        return p

    p = sub.add_parser("status", parents=[common],
                       help="which services are alive and how they are (exit 3: one is dead, 4: one is degraded)")
    p.add_argument("--timeout", type=float, default=2.0, help="how long to wait for the hub's answer")
    p.add_argument("--wait", type=float, default=0.0, metavar="SECONDS",
                   help="first wait (up to SECONDS) until the hub answers and every service is alive")
    p.set_defaults(run=cmd_status)
    p = sub.add_parser("cells", parents=[common], help="the cells present on the fabric and their services")
    p.add_argument("--timeout", type=float, default=2.0, help="how long to wait for the hub's answer")
    p.set_defaults(run=cmd_cells)
    simple("position", lambda c, a: c.position(), _pose_text, "TCP pose and joints of the twin now")
    simple("home", lambda c, a: c.home(), _ack_text, "collision-checked joint move to home")
    p = simple("jog", lambda c, a: c.jog(a.x, a.y, a.z, a.speed), _ack_text,
               "move the nozzle by hand: a straight, collision-checked move in the plate frame (not while printing)")
    for axis in "xyz":
        p.add_argument(f"--{axis}", type=float, default=0.0, metavar="MM", help=f"distance along the plate's {axis}")
    p.add_argument("--speed", type=float, default=20.0, metavar="MM_S", help="the move's speed (default 20 mm/s)")
    p = simple("extrude", lambda c, a: c.extrude(a.length, a.speed), _ack_text,
               "push filament by hand (a negative length pulls it back); the nozzle must be hot")
    p.add_argument("length", type=float, metavar="MM", help="filament length (e.g. 20 to purge, -5 to retract)")
    p.add_argument("--speed", type=float, default=2.0, metavar="MM_S", help="feed rate (default 2 mm/s)")
    p = simple("start", lambda c, a: c.start(rtf=a.rtf, from_layer=_layer_index(a.layer)), _ack_text,
               "start printing the loaded program (again, or from a layer of the part on the plate)")
    p.add_argument("--layer", type=int, default=None, metavar="N", help="start at layer N (1 = the first)")
    p.add_argument("--rtf", type=float, default=None, help="real-time factor (0 = max; default: keep the current)")
    p = simple("resume", lambda c, a: c.resume(rtf=a.rtf), _ack_text, "resume a paused print")
    p.add_argument("--rtf", type=float, default=None, help="real-time factor (0 = max; default: keep the current)")
    p = simple("recover", lambda c, a: c.recover(rtf=a.rtf, from_layer=_layer_index(a.layer)), _ack_text,
               "after a crash: collision-checked move back to the interrupted spot (or a layer's start), go on")
    p.add_argument("--layer", type=int, default=None, metavar="N", help="go on from the start of layer N instead")
    p.add_argument("--rtf", type=float, default=None, help="real-time factor (0 = max; default: keep the current)")
    simple("pause", lambda c, a: c.pause(), _ack_text, "pause: extruder off, retract, lift")
    simple("stop", lambda c, a: c.stop(), _ack_text, "abort the print safely")
    simple("plate-clear", lambda c, a: c.clear_plate(), _ack_text,
           "say the part is off the plate (a print from the start, or the next job, needs it)")
    simple("collisions", lambda c, a: c.collisions(), _collision_text, "sweep the loaded program for collisions")
    p = sub.add_parser("calibrate", parents=[common], help="probe the plate and fit the work object")
    p.set_defaults(run=cmd_calibrate)
    simple("ready", lambda c, a: c.ready(), _ready_text, "station-ready checklist (exit 2: NOT READY)",
           exit_code=lambda r: 0 if r.ready else NOT_READY_EXIT)
    simple("time", lambda c, a: c.time(), _time_text, "simulation time: elapsed, total, remaining")
    simple("state", lambda c, a: c.state(), None, "the station's state snapshot")
    p = simple("events", lambda c, a: c.events(a.since, kinds=a.kind), _events_text, "event history")
    p.add_argument("--since", type=int, default=0)
    p.add_argument("--kind", action="append", metavar="KIND",
                   help="only these kinds (repeat): started, layer, paused, finished, fault, override, ...")
    p = simple("override", lambda c, a: c.overrides(speed_r=a.speed, flow_r=a.flow, nozzle_c=a.nozzle, bed_c=a.bed),
               None, "live overrides: speed, flow, temperatures")
    for flag in ("speed", "flow", "nozzle", "bed"):
        p.add_argument(f"--{flag}", type=float, default=None)
    p = simple("rtf", lambda c, a: c.set_rtf(a.factor), lambda st: f"real-time factor now "
               f"{'max' if st.rtf == 0 else f'{st.rtf:g}'}", "change the simulation speed live")
    p.add_argument("factor", type=float, help="1 = real time, 10 = ten times faster, 0 = as fast as possible")
    p = sub.add_parser("watch", parents=[common], help="follow a telemetry topic")
    p.add_argument("topic", choices=("pose", "extrusion", "state", "temps", "events"))
    p.add_argument("--count", type=int, default=0, help="stop after N messages (0 = forever)")
    p.add_argument("--timeout", type=float, default=0.0, help="stop after this long without a message")
    p.set_defaults(run=cmd_watch)
    p = sub.add_parser("mesh", parents=[common], help="export the as-printed part, or its bead list")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--format", choices=s.station.MESH_FORMATS, default="stl",
                   help="stl or glb: the as-printed mesh; csv: one row per bead (start, end, volume)")
    p.set_defaults(run=cmd_mesh)
