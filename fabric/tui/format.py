"""Text the console shows: durations, the ETA, times of day, events, job rows and records (pure functions,
tested alone)."""
from __future__ import annotations

import time

from fabric import schemas as s
from fabric.printjobs.history import (
    duration_text,
    estimate_text,
    material_text,
    override_lines,
    segment_lines,
    state_text,
)
from fabric.schemas import states

__all__ = ["duration_text", "eta_text", "layer_text", "clock_text", "event_data_text", "job_outcome", "job_report",
           "plate_text", "STATE_STYLE"]

STATE_STYLE = {states.Station.IDLE: "white on grey23", states.Station.READY: "black on green",
               states.Station.PRINTING: "black on green", states.Station.MOVING: "black on dark_cyan",
               states.Station.PAUSED: "black on yellow", states.Station.STOPPED: "white on dark_orange3",
               states.Station.FAULT: "bold white on red", states.Station.INTERRUPTED: "bold white on red"}


def layer_text(st: s.StationState) -> str:
    """Layer n/N as people count (the wire's layer is 0-based, -1 before the first)."""
    return f"layer {st.layer + 1 if st.layer >= 0 else 0}/{st.layers_total}"


def eta_text(st: s.StationState, now_s: float) -> str:
    """When the print ends, always on the wall clock (``now_s``) at the current real-time factor: the time of day
    while printing, how long it will take once resumed while paused; at max speed there is no wall-clock time to
    say (the simulation runs as fast as the host can)."""
    state = states.Station(st.state)
    if not (state.in_print or state is states.Station.MOVING) or st.total_s <= 0:
        return ""
    if st.rtf == 0:
        return "at max speed"
    wall_s = st.remaining_s / st.rtf
    if state is states.Station.PAUSED:
        return f"paused: {duration_text(wall_s)} to go once resumed"
    return f"ETA {time.strftime('%H:%M:%S', time.localtime(now_s + wall_s))} (in {duration_text(wall_s)})"


def plate_text(st: s.StationState | None, whose: bool = True) -> str:
    """What is on the plate, as the station says ("" before it has said anything); ``whose``: the job whose part
    it is, too."""
    if st is None:
        return ""
    if st.plate_clear:
        return "plate clear"
    of = (f" of job {st.plate_job_id}" if st.plate_job_id else " printed by hand") if whose else ""
    return f"plate holds {'the' if whose else 'a'} part{of} ({st.plate_mm3:.0f} mm3)"


def clock_text(t_s: float) -> str:
    """The time of day of ``t_s`` (wall clock, local time), or "-" when there is none (0)."""
    return time.strftime("%H:%M:%S", time.localtime(t_s)) if t_s else "-"


def event_data_text(data: dict) -> str:
    """An event's data as ``key=value`` pairs (floats to 6 significant digits)."""
    return "  ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}" for k, v in data.items())


def job_outcome(rec: s.JobRecord) -> str:
    return rec.state + (f": {rec.reason}" if rec.reason else "")


def job_report(rec: s.JobRecord) -> str:
    """A job's whole record, as the job dialog shows it."""
    when = lambda t: time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t)) if t else "-"  # noqa: E731
    lines = [f"{rec.filename} ({rec.source}, {rec.backend or '-'} / {rec.profile or '-'})",
             f"state     {state_text(rec)}"
             + (f", waiting for the {rec.waiting_for}" if rec.waiting_for else ""),
             f"stage     {rec.stage or '-'}"]
    if rec.reason:
        lines.append(f"reason    {rec.reason}")
    lines += [f"created   {when(rec.created_s)}", f"started   {when(rec.started_s)}", f"ended     {when(rec.ended_s)}"]
    if rec.started_s:
        lines.append(f"duration  {duration_text(rec.sim_elapsed_s)} simulated, "
                     f"{duration_text(rec.wall_elapsed_s)} wall")
        lines.append(f"material  {material_text(rec)}")
    if rec.plan is not None:
        p = rec.plan
        lines.append(f"plan      {p.layers} layers, {p.moves} moves, {p.extruded_mm3:.0f} mm3, "
                     f"{estimate_text(p.estimate_s, duration_text)}")
        lines.append(f"filament  {p.filament_diameter_mm:g} mm ({p.material_source})"
                     + (f", {p.material}" if p.material else ""))
        fu = p.first_unreachable
        if fu is not None:             # which joint, its angle and limit, the line (and how many more)
            lines.append(f"reach     NOT RUNNABLE at G-code line {fu.gcode_line}: {fu.why()}{p.counted()}")
    if rec.segments:
        lines.append("runs")
        lines += [f"  {line}" for line in segment_lines(rec)]
    if rec.live_overrides:
        lines.append("overrides")
        lines += [f"  {line}" for line in override_lines(rec)]
    if rec.collisions is not None:
        c, hit = rec.collisions, rec.collisions.first_hit
        if c.collision_free:
            lines.append("check     collision-free")
        elif hit is not None and hit.message:
            lines.append(f"check     COLLISION at {hit.message}")
        else:
            lines.append("check     COLLISION" + (f" {hit.body_a} <-> {hit.body_b}" if hit is not None else ""))
    if rec.error is not None:
        lines.append(f"error     [{rec.error.code}] {rec.error.message}")
    return "\n".join(lines)
