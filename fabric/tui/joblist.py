"""Which jobs the console lists: every job not ended (the queue, what is on the station) and the latest ended
ones (the history), however long the supervisor's history has grown."""
from __future__ import annotations

from typing import Any

from fabric import schemas as s
from fabric.schemas import states

__all__ = ["HISTORY_SHOWN", "console_jobs"]

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
