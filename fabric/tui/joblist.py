"""Which jobs the console lists: every job not ended (the queue, what is on the station) and the latest ended
ones (the history), however long the supervisor's history has grown; and how the list follows a change of the
queue that any client made (``supervisor/queue``) without asking for it again."""
from __future__ import annotations

from typing import Any

from fabric import schemas as s
from fabric.schemas import states

__all__ = ["HISTORY_SHOWN", "after_change", "console_jobs", "not_listed"]

HISTORY_SHOWN = 200          # the most ended jobs the Jobs screen lists (the newest)
ACTIVE_STATES = tuple(st.value for st in states.PrintJob if not st.ended)


def console_jobs(client: Any) -> list[s.JobRecord]:
    """The jobs not ended, in queue order, then the ``HISTORY_SHOWN`` ended ones submitted last (three
    queries, each a page; blocking: from a worker thread)."""
    active = client.jobs(0, s.MAX_JOBS_PAGE, ACTIVE_STATES).jobs
    ended_total = client.jobs(0, 0, s.FINAL_JOB_STATES).total
    ended = client.jobs(max(0, ended_total - HISTORY_SHOWN), HISTORY_SHOWN, s.FINAL_JOB_STATES).jobs
    seen: set[str] = set()
    out: list[s.JobRecord] = []
    for rec in [*active, *ended]:          # a job that ended between two queries is listed once
        if rec.job_id not in seen:
            seen.add(rec.job_id)
            out.append(rec)
    return out


def after_change(jobs: list[s.JobRecord], change: s.QueueChange) -> list[s.JobRecord]:
    """The list once ``change`` is taken: a removed job is off it, and the waiting jobs it holds are in the
    queue's order after the change, in the places waiting jobs held (every other job keeps its place). A job
    submitted is not added here: its record comes on ``supervisor/jobs`` (:func:`not_listed` tells)."""
    kept = [r for r in jobs if not (change.kind == "removed" and r.job_id == change.job_id)]
    order = {job_id: k for k, job_id in enumerate(change.waiting)}
    places = [i for i, r in enumerate(kept) if r.job_id in order]
    in_order = sorted((kept[i] for i in places), key=lambda r: order[r.job_id])
    for i, rec in zip(places, in_order, strict=True):
        kept[i] = rec
    return kept


def not_listed(jobs: list[s.JobRecord], change: s.QueueChange) -> list[str]:
    """The waiting jobs ``change`` names that the list does not hold (their records are still to come)."""
    listed = {r.job_id for r in jobs}
    return [job_id for job_id in change.waiting if job_id not in listed]
