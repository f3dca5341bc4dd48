"""The console's commands: one table of what each key does, how it is confirmed and how its answer reads."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from fabric import schemas as s
from fabric.client import Client

__all__ = ["Command", "COMMANDS", "Bound", "OVERRIDE_BOUNDS", "RTF_BOUND", "LAYER_BOUND", "describe"]


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
RTF_BOUND = Bound("rtf", "real-time factor (0 = max)", 0.0, 1e6, "x")
LAYER_BOUND = Bound("layer", "from layer (1 = first)", 1, 1_000_000, "", integer=True)


@dataclass(frozen=True)
class Command:
    """``call(client, values)`` runs it; ``confirm`` (a question) guards destructive ones; ``asks``
    are the values a dialog collects first; ``report``: the answer is shown whole in a dialog."""

    name: str
    label: str
    call: Callable[[Client, dict[str, Any]], Any]
    confirm: str = ""
    asks: tuple[Bound, ...] = field(default=())
    report: bool = False


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
    Command("stop", "stop", lambda c, v: c.stop(), confirm="Stop the print? It cannot be resumed."),
    Command("home", "home", lambda c, v: c.home(), confirm="Move the robot home (collision-checked joint move)?"),
    Command("calibrate", "calibrate", lambda c, v: c.calibrate(),
            confirm="Probe the plate and replace the work object?", report=True),
    Command("overrides", "overrides", lambda c, v: c.overrides(**v), asks=OVERRIDE_BOUNDS),
    Command("rtf", "sim speed", lambda c, v: c.set_rtf(v["rtf"]),
            asks=(Bound("rtf", RTF_BOUND.label, RTF_BOUND.lo, RTF_BOUND.hi, "x", optional=False),)),
)}


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
        elif (h := result.first_hit) is not None:
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
