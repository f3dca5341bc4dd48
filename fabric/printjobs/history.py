"""A job's print history in words: its segments (each run of the print) with their totals, and the overrides set
while it printed. Pure functions of the record, shared by ``fabric-cli job show`` and the console."""
from __future__ import annotations

import time
from collections.abc import Callable

from fabric import schemas as s
from fabric.schemas.states import PrintJob

__all__ = ["duration_text", "segment_lines", "override_lines", "material_text", "estimate_text", "state_text"]

def duration_text(seconds: float) -> str:
    """``42s``, ``3m12s``, ``2h05m``."""
    seconds = max(0.0, float(seconds))
    if seconds < 60:
        return f"{seconds:.0f}s"
    if seconds < 3600:
        return f"{int(seconds // 60)}m{int(seconds % 60):02d}s"
    return f"{int(seconds // 3600)}h{int(seconds % 3600 // 60):02d}m"


def _clock(t_s: float) -> str:
    return time.strftime("%H:%M:%S", time.localtime(t_s)) if t_s else "-"


def estimate_text(estimate_s: float, words: Callable[[float], str] = lambda t: f"{t:.1f} s") -> str:
    """``estimate 1354.0 s`` (``words`` writes the time); a plan that cannot be timed (its targets are not all
    reachable: the planner says -1) has ``no time estimate``."""
    return f"estimate {words(estimate_s)}" if estimate_s >= 0.0 else "no time estimate"


def state_text(rec: s.JobRecord) -> str:
    """The job's state, ``queued (prepared)`` while a queued job is sliced, planned and checked ahead (once it
    is on the station, or has ended, being prepared says nothing more)."""
    return rec.state + (" (prepared)" if rec.prepared and rec.state == PrintJob.QUEUED else "")


def material_text(rec: s.JobRecord) -> str:
    """``3900 mm3 deposited, 1296 mm of filament``. The volume follows the print as it goes; the filament is
    the station's count when a run ends, so a run still open is said to be::

        571 mm3 deposited, filament counted when the run ends
        1839 mm3 deposited, 612 mm of filament by the end of run 1 (run 2 still open)
    """
    volume = f"{rec.deposited_mm3:.0f} mm3 deposited"
    open_runs = [i for i, seg in enumerate(rec.segments, 1) if not seg.ended]
    if not open_runs:
        return f"{volume}, {rec.filament_mm:.0f} mm of filament"
    if rec.filament_mm <= 0.0:
        return f"{volume}, filament counted when the run ends"
    return (f"{volume}, {rec.filament_mm:.0f} mm of filament by the end of run {open_runs[-1] - 1} "
            f"(run {open_runs[-1]} still open)")


def segment_lines(rec: s.JobRecord) -> list[str]:
    """One line per run of the print, then the totals when there is more than one::

        1 22:00:00 start    layers 1-25   16m20s  3900 mm3  stopped (1 pause)
        2 22:20:00 restart  layers 25-40  10m07s  2629 mm3  finished
          in all 2 runs                   26m27s  6529 mm3  15m00s wall
    """
    lines = []
    for i, seg in enumerate(rec.segments, 1):
        first = seg.from_layer + 1 if seg.began != "start" else 1
        layers = f"layers {first}-{seg.last_layer + 1}" if seg.last_layer >= 0 else "no layer yet"
        notes = [f"{seg.pauses} pause{'s' if seg.pauses != 1 else ''}"] if seg.pauses else []
        if seg.reason and seg.ended in ("failed", "interrupted"):
            notes.append(seg.reason)
        ended = (seg.ended or "running") + (f" ({', '.join(notes)})" if notes else "")
        lines.append(f"{i} {_clock(seg.started_s)} {seg.began:<8} {layers:<13} {duration_text(seg.sim_s):>6}  "
                     f"{seg.deposited_mm3:.0f} mm3  {ended}")
    if len(rec.segments) > 1:
        lines.append(f"  {'in all ' + str(len(rec.segments)) + ' runs':<31} {duration_text(rec.sim_elapsed_s):>6}  "
                     f"{rec.deposited_mm3:.0f} mm3  {duration_text(rec.wall_elapsed_s)} wall")
    return lines


def override_lines(rec: s.JobRecord) -> list[str]:
    """One line per override set while the job printed (``10:05:40 layer 3: speed x1.50, flow x1.10``)."""
    lines = []
    for o in rec.live_overrides:
        parts = [f"speed x{o.speed_r:.2f}" if o.speed_r is not None else "",
                 f"flow x{o.flow_r:.2f}" if o.flow_r is not None else "",
                 f"nozzle {o.nozzle_c:.0f} C" if o.nozzle_c is not None else "",
                 f"bed {o.bed_c:.0f} C" if o.bed_c is not None else ""]
        where = f"layer {o.layer + 1}" if o.layer >= 0 else "before the first layer"
        lines.append(f"{_clock(o.wall_s)} {where}: " + ", ".join(p for p in parts if p))
    return lines
