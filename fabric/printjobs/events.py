"""How a print job's record follows the station's events (a pure function: the supervisor applies it).

A job's print is a list of segments (:class:`~fabric.schemas.JobSegment`): each
run of its program on the station, from how it began (the ``started`` event,
from the beginning or at a layer; ``recovered`` after an interruption) to how it
ended (``finished``, ``stopped``, ``fault``, ``interrupted``). The record's
state, reason and stage follow the last event; its start is the first
segment's, its durations and material the segments' totals. The twin counts
what a job deposited across its segments (a restart at a layer or a recovery
goes on with the same count), so a segment's material is the count at its end
less what the segments before it deposited.
"""
from __future__ import annotations

from fabric import schemas as s
from fabric.schemas.states import PrintJob

__all__ = ["JOB_EVENT_KINDS", "apply_event", "job_id_of_event", "run_share_mm3"]

_STATE_OF = {"started": PrintJob.PRINTING, "resumed": PrintJob.PRINTING, "recovered": PrintJob.PRINTING,
             "paused": PrintJob.PAUSED, "finished": PrintJob.FINISHED, "stopped": PrintJob.STOPPED,
             "fault": PrintJob.FAILED, "interrupted": PrintJob.INTERRUPTED}
_ENDED_AS = {"finished": "finished", "stopped": "stopped", "fault": "failed", "interrupted": "interrupted"}
_OVERRIDES = ("speed_r", "flow_r", "nozzle_c", "bed_c")

JOB_EVENT_KINDS = ("layer", "override", *_STATE_OF)


def job_id_of_event(event: s.Event) -> str:
    """The print job an event is about ("" when it is about none): the station names the job
    loaded when it happened in the event's data."""
    if event.kind not in JOB_EVENT_KINDS or not isinstance(event.data, dict):
        return ""
    return str(event.data.get("job_id", ""))


def apply_event(rec: s.JobRecord, event: s.Event, wall_s: float) -> bool:
    """Update ``rec`` from a station event received at wall time ``wall_s``; True when it changed.

    Lifecycle events move the job's state (started/resumed/recovered -> printing, paused, finished,
    stopped, fault -> failed, interrupted), begin and end its segments and carry the station's clock;
    the end of a segment records what the print has deposited (and the share of the plan's volume that
    is); a pause records the twin's reason (the operator, or the cold-extrusion interlock). Layer
    events track the layer; override events are kept in the record. A job already final changes only
    when its program is started again on the station (restarted at a layer after a stop)."""
    kind = event.kind
    data = event.data if isinstance(event.data, dict) else {}
    if kind == "override":
        return _override(rec, event, data, wall_s)
    if kind == "layer" and rec.state == PrintJob.PRINTING:
        rec.layer = int(event.layer)
        rec.stage = f"printing layer {event.layer + 1}"
        seg = _running(rec, event, data, wall_s)
        seg.last_layer = int(event.layer)
        _clock(rec, seg, event, wall_s)
        return True
    if kind not in _STATE_OF:
        return False
    if rec.state.ended and kind != "started":    # a stopped print restarted at a layer
        return False
    rec.state = _STATE_OF[kind]
    rec.updated_s = wall_s
    if kind in ("started", "recovered"):
        seg = _begin(rec, event, data, wall_s)
    else:
        seg = _running(rec, event, data, wall_s)
    if kind == "started":
        rec.ended_s, rec.reason = 0.0, ""
        rec.stage = "printing" if seg.began == "start" else f"printing from layer {seg.from_layer + 1}"
    elif kind in ("resumed", "recovered"):
        rec.reason, rec.stage = "", "printing"
    elif kind == "paused":         # the twin says why: the operator, or its cold-extrusion interlock
        rec.stage, rec.reason = "paused", str(data.get("reason") or "paused by the operator")
        seg.pauses += 1
    else:                                            # the segment ended: the print, or an interruption
        if kind == "interrupted":
            rec.reason = str(data.get("reason", "interrupted"))
            rec.stage = "interrupted: recover to go on"
        else:
            rec.ended_s = wall_s
            rec.stage = rec.state
            rec.reason = {"fault": str(data.get("reason", "fault")),
                          "stopped": "stopped by the operator"}.get(kind, "")
        _deposited(rec, seg, data)
        seg.ended, seg.ended_s, seg.reason = _ENDED_AS[kind], wall_s, rec.reason
        if kind == "finished":
            rec.progress_r = 1.0
    _clock(rec, seg, event, wall_s)
    return True


def _begin(rec: s.JobRecord, event: s.Event, data: dict, wall_s: float) -> s.JobSegment:
    """A new segment: a ``started`` event (from the beginning, or at a layer), or ``recovered``."""
    previous = _open(rec)
    if previous is not None:                          # it never said how it ended (e.g. a missed event)
        previous.ended, previous.ended_s = "interrupted", wall_s
    if event.kind == "recovered":
        began, layer = "recover", max(int(data.get("from_layer", event.layer)), 0)
    else:
        layer = int(data.get("from_layer", 0) or 0)
        began = "restart" if int(data.get("from_row", 0) or 0) > 0 else "start"
    last = {"start": -1, "restart": layer, "recover": int(event.layer)}[began]   # a layer event comes when it changes
    seg = s.JobSegment(began=began, from_layer=layer, started_s=wall_s, t_sim_start_s=float(event.t_sim_s),
                       last_layer=last)
    rec.segments.append(seg)
    if not rec.started_s:
        rec.started_s = wall_s
    return seg


def _open(rec: s.JobRecord) -> s.JobSegment | None:
    return rec.segments[-1] if rec.segments and not rec.segments[-1].ended else None


def _running(rec: s.JobRecord, event: s.Event, data: dict, wall_s: float) -> s.JobSegment:
    """The segment running now; one made from the record for a print that began before records had them
    (the station says in each job event how long the print has run)."""
    seg = _open(rec)
    if seg is None:
        t0 = float(event.t_sim_s) - float(data.get("elapsed_s", rec.sim_elapsed_s))
        seg = s.JobSegment(began="start", started_s=rec.started_s or wall_s, t_sim_start_s=t0,
                           deposited_mm3=0.0, last_layer=rec.layer)
        rec.segments.append(seg)
        rec.started_s = rec.started_s or wall_s
    return seg


def _clock(rec: s.JobRecord, seg: s.JobSegment, event: s.Event, wall_s: float) -> None:
    """The running segment's time so far, and the record's totals over its segments."""
    seg.sim_s = max(float(event.t_sim_s) - seg.t_sim_start_s, seg.sim_s)
    rec.sim_elapsed_s = sum(x.sim_s for x in rec.segments)
    rec.wall_elapsed_s = sum(max((x.ended_s or wall_s) - x.started_s, 0.0) for x in rec.segments)


def run_share_mm3(rec: s.JobRecord, seg: s.JobSegment) -> float:
    """What run ``seg`` deposited: the print's volume so far (the twin counts over all its runs) less the
    other runs'."""
    return max(rec.deposited_mm3 - sum(x.deposited_mm3 for x in rec.segments if x is not seg), 0.0)


def _deposited(rec: s.JobRecord, seg: s.JobSegment, data: dict) -> None:
    """What the print has deposited so far (the twin's count over its segments), this segment's share, and
    the share of the plan's volume that is (when the event says it)."""
    if "extruded_mm3" not in data:
        return
    rec.deposited_mm3 = float(data["extruded_mm3"])
    rec.filament_mm = float(data.get("filament_mm", rec.filament_mm))
    seg.deposited_mm3 = run_share_mm3(rec, seg)
    planned = rec.plan.extruded_mm3 if rec.plan is not None else 0.0
    if planned > 0:
        rec.progress_r = min(max(rec.deposited_mm3 / planned, 0.0), 1.0)


def _override(rec: s.JobRecord, event: s.Event, data: dict, wall_s: float) -> bool:
    """An override set while the job was on the station: kept in its record."""
    if not rec.state.on_station:
        return False
    values = {k: float(data[k]) for k in _OVERRIDES if isinstance(data.get(k), (int, float))}
    if not values:
        return False
    rec.live_overrides.append(s.JobOverride(wall_s=wall_s, t_sim_s=float(event.t_sim_s), layer=int(event.layer),
                                            **values))
    rec.updated_s = wall_s
    return True
