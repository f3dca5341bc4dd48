"""The console's commands: one table of what each key does, how it is confirmed and how its answer reads."""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from fabric import schemas as s
from fabric.client import Client
from fabric.schemas import states
from fabric.wire.errors import FabricError

__all__ = ["Command", "COMMANDS", "Bound", "OVERRIDE_BOUNDS", "RTF_BOUND", "LAYER_BOUND", "JOG_BOUNDS",
           "EXTRUDE_BOUNDS", "PRESETS", "Preset", "describe", "refusal", "refused_hit"]


@dataclass(frozen=True)
class Bound:
    """One value a dialog asks for: its label, limits and unit (``optional``: may be left empty)."""

    name: str
    label: str
    lo: float
    hi: float
    unit: str = ""
    optional: bool = True
    integer: bool = False


# Bounds as the station's schemas declare them (fabric.schemas.station: Overrides, StartRequest).
OVERRIDE_BOUNDS = (Bound("speed_r", "speed", 0.05, 4.0, "x"), Bound("flow_r", "flow", 0.0, 4.0, "x"),
                   Bound("nozzle_c", "nozzle", 0.0, 500.0, "C"), Bound("bed_c", "bed", 0.0, 200.0, "C"))
RTF_BOUND = Bound("rtf", "sim speed", 0.0, 1e6, "x real time, 0 = max")
LAYER_BOUND = Bound("layer", "from layer", 1, 1_000_000, "1 = first", integer=True)
STILL = tuple(st for st in states.Station if st.free)          # station states in which the robot may be moved
IN_PRINT = tuple(st for st in states.Station if st.in_print)    # a print is under way: it can be stopped
# Jog and manual extrude (fabric.schemas.station: JogRequest, ExtrudeRequest); empty = 0 / the default
JOG_BOUNDS = (Bound("dx_mm", "x", -200.0, 200.0, "mm"), Bound("dy_mm", "y", -200.0, 200.0, "mm"),
              Bound("dz_mm", "z", -200.0, 200.0, "mm"), Bound("speed_mm_s", "speed", 0.1, 200.0, "mm/s, 20"))
EXTRUDE_BOUNDS = (Bound("length_mm", "filament", -100.0, 500.0, "mm, < 0 pulls", optional=False),
                  Bound("speed_mm_s", "feed", 0.05, 50.0, "mm/s, 2"))


@dataclass(frozen=True)
class Command:
    """``call(client, values)`` runs it; ``confirm`` (a question) guards destructive ones; ``asks``
    are the values a dialog collects first; ``report``: the answer is shown whole in a dialog.
    ``allowed_in``: the station states it makes sense in; in another one the console says so at once,
    rather than asking first and being refused after (the station still decides)."""

    name: str
    label: str
    call: Callable[[Client, dict[str, Any]], Any]
    confirm: str = ""
    asks: tuple[Bound, ...] = field(default=())
    report: bool = False
    allowed_in: tuple[states.Station, ...] = ()


def _layer(values: dict[str, Any]) -> int:
    n = values.get("layer")
    return -1 if n is None else int(n) - 1      # the wire counts layers from 0


COMMANDS: dict[str, Command] = {c.name: c for c in (
    Command("position", "position", lambda c, v: c.position(), report=True),
    Command("time", "time", lambda c, v: c.time(), report=True),
    Command("ready", "ready?", lambda c, v: c.ready(), report=True),
    Command("collisions", "collisions", lambda c, v: c.collisions(), report=True),
    Command("start", "start", lambda c, v: c.start(rtf=v.get("rtf"), from_layer=_layer(v)),
            asks=(LAYER_BOUND, RTF_BOUND)),
    Command("pause", "pause", lambda c, v: c.pause()),
    Command("resume", "resume", lambda c, v: c.resume(rtf=v.get("rtf")), asks=(RTF_BOUND,)),
    Command("recover", "recover", lambda c, v: c.recover(rtf=v.get("rtf"), from_layer=_layer(v)),
            asks=(LAYER_BOUND, RTF_BOUND)),
    Command("stop", "stop", lambda c, v: c.stop(), allowed_in=IN_PRINT,
            confirm="Stop the print? The extruder and the heaters go off and the robot moves clear; the part stays "
                    "on the plate. A stopped print is not resumed, but it can be restarted at a layer "
                    "(s, then the layer)."),
    Command("home", "home", lambda c, v: c.home(), allowed_in=STILL,
            confirm="Move the robot home (a collision-checked joint move)?"),
    Command("calibrate", "calibrate", lambda c, v: c.calibrate(), allowed_in=STILL,
            confirm="Probe the plate and replace the work object? A loaded program is unloaded (plan it again).",
            report=True),
    Command("jog", "jog", lambda c, v: c.jog(v.get("dx_mm") or 0.0, v.get("dy_mm") or 0.0, v.get("dz_mm") or 0.0,
                                              speed_mm_s=v.get("speed_mm_s") or 20.0),
            asks=JOG_BOUNDS, allowed_in=STILL),
    Command("extrude", "extrude", lambda c, v: c.extrude(v["length_mm"], speed_mm_s=v.get("speed_mm_s") or 2.0),
            asks=EXTRUDE_BOUNDS, allowed_in=STILL),
    Command("overrides", "overrides", lambda c, v: c.overrides(**v), asks=OVERRIDE_BOUNDS),
    Command("rtf", "sim speed", lambda c, v: c.set_rtf(v["rtf"]),
            asks=(Bound("rtf", RTF_BOUND.label, RTF_BOUND.lo, RTF_BOUND.hi, "x", optional=False),)),
)}


@dataclass(frozen=True)
class Preset:
    """Set points of a material, for preheating (0 = heater off)."""

    name: str
    nozzle_c: float
    bed_c: float


PRESETS = (Preset("PLA", 215.0, 60.0), Preset("PETG", 240.0, 80.0), Preset("ABS", 250.0, 100.0),
           Preset("TPU", 225.0, 50.0), Preset("cool down", 0.0, 0.0))


def refusal(cmd: Command, state: states.Station | None) -> str:
    """Why ``cmd`` is not asked for in station state ``state`` ("" when it is, or the state is not known)."""
    if not cmd.allowed_in or state is None or state in cmd.allowed_in:
        return ""
    if cmd.name == "stop":
        return f"nothing to stop: the station is {state}"
    why = "stop the print first (x)" if state.in_print else (
        "recover it first (v)" if state is states.Station.INTERRUPTED else "wait until it has stopped moving")
    return f"cannot {cmd.label} while {state}: {why}"


def describe(name: str, result: Any) -> tuple[str, str]:
    """(one line, whole report) for a command's answer."""
    if isinstance(result, s.ReadyReport):
        bad = [c for c in result.checks if not c.ok]
        line = "READY" if result.ready else "NOT READY: " + "; ".join(
            f"{c.name}" + (f" ({c.detail})" if c.detail else "") for c in bad)
        report = "\n".join(f"{'✔' if c.ok else '✘'} {c.name}" + (f": {c.detail}" if c.detail else "")
                           for c in result.checks)
        return line, f"{'READY' if result.ready else 'NOT READY'}\n\n{report}"
    if isinstance(result, s.CollisionReport):
        if result.collision_free:
            line = (f"collision-free: {result.checked_configs} configurations, clearance "
                    f"{result.min_distance_mm:.1f} mm")
        elif (h := result.first_hit) is not None and h.message:
            line = f"COLLISION at {h.message}"      # line, move, layer, bodies, where and when
        elif h is not None:
            line = (f"COLLISION at t={h.t_s:.1f} s, G-code line {h.gcode_line}, layer {h.layer + 1}: "
                    f"{h.body_a} <-> {h.body_b}")
        else:
            line = "COLLISION"                  # a report without its first hit (not sent by the checker)
        return line, line
    if isinstance(result, s.CalibrationReport):
        line = (f"plate corrected by ({', '.join(f'{v:.3f}' for v in result.correction_xyz_mm)}) mm, "
                f"residual {result.residual_rms_mm:.4f} mm over {result.points} probes")
        return line, line
    if isinstance(result, s.Pose):
        x, y, z = result.xyz_mm
        bx, by, bz = result.base_xyz_mm
        report = (f"TCP plate ({x:.2f}, {y:.2f}, {z:.2f}) mm\nTCP base  ({bx:.2f}, {by:.2f}, {bz:.2f}) mm\n"
                  f"joints    {', '.join(f'{v:.2f}' for v in result.q_deg)} deg\nt_sim     {result.t_sim_s:.2f} s")
        return f"TCP ({x:.2f}, {y:.2f}, {z:.2f}) mm", report
    if isinstance(result, s.TimeInfo):
        line = (f"elapsed {result.elapsed_s:.1f} s, total {result.total_s:.1f} s, remaining "
                f"{result.remaining_s:.1f} s (estimate {result.estimate_s:.1f} s) [{result.state}]")
        return line, line.replace(", ", "\n")
    if isinstance(result, s.StationState):
        rtf = "max" if result.rtf == 0 else f"{result.rtf:g}"
        line = f"speed x{result.speed_r:.2f}  flow x{result.flow_r:.2f}  rtf {rtf}"
        return line, line
    text = getattr(result, "message", "") or "ok"
    return text, text


def refused_hit(err: FabricError) -> s.CollisionHit | None:
    """The first hit a refused live move names (a station's ``collision`` error carries it in its details:
    home, recover, a restart at a layer and its descent), or None."""
    if err.code != "collision" or "body_a" not in err.details or "body_b" not in err.details:
        return None
    names = {f.name for f in dataclasses.fields(s.CollisionHit)}
    return s.CollisionHit(**{k: v for k, v in err.details.items() if k in names - {"message"}}, message=err.message)
