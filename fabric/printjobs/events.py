"""How a print job's record follows the station's events (a pure function: the supervisor applies it)."""
from __future__ import annotations

from fabric import schemas as s

__all__ = ["JOB_EVENT_KINDS", "apply_event", "job_id_of_event"]

_STATE_OF = {"started": "printing", "resumed": "printing", "recovered": "printing", "paused": "paused",
             "finished": "finished", "stopped": "stopped", "fault": "failed", "interrupted": "interrupted"}


JOB_EVENT_KINDS = ("layer", *_STATE_OF)


def job_id_of_event(event: s.Event) -> str:
    """The print job an event is about ("" when it is about none): the station names the job
    loaded when it happened in the event's data."""
    if event.kind not in JOB_EVENT_KINDS or not isinstance(event.data, dict):
        return ""
    return str(event.data.get("job_id", ""))


def apply_event(rec: s.JobRecord, event: s.Event, wall_s: float) -> bool:
    """Update ``rec`` from a station event received at wall time ``wall_s``; True when it changed.

    Lifecycle events move the job's state (started/resumed/recovered -> printing, paused, finished,
    stopped, fault -> failed, interrupted) and carry its simulated time so far; the end of a print and
    an interruption also record what it deposited (and the share of the plan's volume that is); a pause
    records the twin's reason (the operator, or the cold-extrusion interlock). Layer events track the
    layer. A job already final changes only when its program is started again on the station (e.g.
    restarted at a layer after a stop)."""
    kind = event.kind
    data = event.data if isinstance(event.data, dict) else {}
    if kind == "layer" and rec.state == "printing":
        rec.layer = int(event.layer)
        rec.stage = f"printing layer {event.layer + 1}"
        return True
    if kind not in _STATE_OF:
        return False
    if rec.state in s.FINAL_JOB_STATES and kind != "started":    # a stopped print restarted at a layer
        return False
    new = _STATE_OF[kind]
    rec.state = new
    rec.updated_s = wall_s
    rec.sim_elapsed_s = float(data.get("elapsed_s", rec.sim_elapsed_s))
    if kind == "started":
        rec.started_s, rec.ended_s, rec.reason = wall_s, 0.0, ""
        rec.stage = "printing"
    elif kind in ("resumed", "recovered"):
        rec.reason, rec.stage = "", "printing"
    elif kind == "paused":         # the twin says why: the operator, or its cold-extrusion interlock
        rec.stage, rec.reason = "paused", str(data.get("reason") or "paused by the operator")
    elif kind == "interrupted":
        rec.reason = str(data.get("reason", "interrupted"))
        rec.stage = "interrupted: recover to go on"
        _deposited(rec, data)               # what the print has deposited so far (the twin says it)
    else:                                            # the print ended
        rec.ended_s = wall_s
        rec.stage = new
        if kind == "fault":
            rec.reason = str(data.get("reason", "fault"))
        elif kind == "stopped":
            rec.reason = "stopped by the operator"
        _deposited(rec, data)
        if kind == "finished":
            rec.progress_r = 1.0
    if rec.started_s:
        end = rec.ended_s or wall_s
        rec.wall_elapsed_s = max(end - rec.started_s, 0.0)
    return True


def _deposited(rec: s.JobRecord, data: dict) -> None:
    """The volume and filament an event says the print deposited so far, and the share of the plan's
    volume that is (when the event says it)."""
    if "extruded_mm3" not in data:
        return
    rec.deposited_mm3 = float(data["extruded_mm3"])
    rec.filament_mm = float(data.get("filament_mm", rec.filament_mm))
    planned = rec.plan.extruded_mm3 if rec.plan is not None else 0.0
    if planned > 0:
        rec.progress_r = min(max(rec.deposited_mm3 / planned, 0.0), 1.0)
