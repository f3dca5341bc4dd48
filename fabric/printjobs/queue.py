"""The print queue's rules, as pure functions of the records: which job waits for what, and which loads next.

A prepared job at the head of the queue is loaded when the station has no job
and the plate is clear; every other prepared job says what it waits for (the
jobs ahead of it, the station, or the operator confirming the plate is clear).
The supervisor applies these decisions in its writer (one step each).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from fabric import schemas as s
from fabric.schemas.states import FREE_STATION_STATES, WAITING_JOB_STATES

__all__ = ["WAITING_STATES", "STATION_FREE", "WAITING_TEXT", "PREPARER_FIELDS", "LoadDecision", "next_to_load"]

WAITING_STATES = WAITING_JOB_STATES                               # in the queue, reorderable
STATION_FREE = tuple(x.value for x in FREE_STATION_STATES)       # station states a job may be loaded in
WAITING_TEXT = {"plate": "prepared: confirm the plate is clear (job next)",
                "station": "prepared: waiting for the station to be free",
                "queue": "prepared: waiting behind the jobs ahead of it"}
# what the preparer writes onto a job's record (nothing else: ``start`` or the queue order may change meanwhile)
PREPARER_FIELDS = ("state", "stage", "progress_r", "prepared", "reason", "error", "ended_s", "gcode_id",
                   "program_id", "plan", "collisions")


@dataclass
class LoadDecision:
    """``load``: the job to load now (or None); ``waits``: (job, what it waits for) for the others."""

    load: s.JobRecord | None = None
    waits: list[tuple[s.JobRecord, str]] = field(default_factory=list)


def next_to_load(waiting: list[s.JobRecord], on_station: s.JobRecord | None, plate_clear: bool) -> LoadDecision:
    """Decide from the waiting jobs in queue order, the job on the station (if any) and the plate."""
    decision = LoadDecision()
    if not waiting:
        return decision
    head, rest = waiting[0], waiting[1:]
    decision.waits = [(rec, "queue") for rec in rest]
    if not head.prepared:
        return decision
    if on_station is not None:
        decision.waits.append((head, "station"))
    elif not plate_clear:
        decision.waits.append((head, "plate"))
    else:
        decision.load = head
    return decision
