"""Following jobs to their end: a service's job (slicing, planning) and a print job at the supervisor.

Each reads a snapshot first, then the service's stream; a missed final message
costs a snapshot asked again, never a hang.
"""
from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable

from fabric import schemas as s
from fabric.client.protocols import Caller
from fabric.schemas.states import Job, PrintJob
from fabric.wire.errors import ServiceUnavailable, error_from_code

__all__ = ["wait_job", "wait_print_job"]


def wait_job(client: Caller, service: str, job_id: str, timeout: float = 600.0,
             on_progress: Callable[[s.JobStatus], None] | None = None,
             cancel: threading.Event | None = None) -> s.JobStatus:
    """Follow a job (snapshot, then the progress stream) until it ends; raise its error if it failed. ``cancel``
    set (a service closing) ends the wait within a quarter of a second (ServiceUnavailable)."""
    sub = client.subscribe(service, "progress")
    poll_s = 2.0 if cancel is None else 0.25
    try:
        end = time.monotonic() + timeout
        st = client.call(service, "job", s.JobQuery(job_id=job_id))
        started = time.monotonic()                     # when the snapshot was last asked
        while not st.state.ended:
            if on_progress:
                on_progress(st)
            left = end - time.monotonic()
            if left <= 0:
                raise ServiceUnavailable(f"{service} job {job_id} still {st.state} after {timeout:g} s")
            if cancel is not None and cancel.is_set():
                raise ServiceUnavailable(f"stopped waiting for {service} job {job_id}: closing")
            try:
                msg = sub.get(timeout=min(left, poll_s))
            except queue.Empty:  # a missed final message: ask once more (snapshot)
                if cancel is not None and (cancel.is_set() or time.monotonic() - started < 2.0):
                    continue                               # (polled often to see a cancel: ask only every 2 s)
                st = client.call(service, "job", s.JobQuery(job_id=job_id))
                started = time.monotonic()
                continue
            if msg.job_id == job_id:
                st = msg
        if st.state == Job.FAILED and st.error is not None:
            raise error_from_code(st.error.code, st.error.message, st.error.details)
        if on_progress:
            on_progress(st)                 # the end too: a progress line left at 85 % reads as a job cut short
        return st
    finally:
        sub.close()


def wait_print_job(client: Caller, job_id: str, done: Callable[[s.JobRecord], bool], timeout: float = 600.0,
                   on_change: Callable[[s.JobRecord], None] | None = None) -> s.JobRecord:
    """Follow a print job (its record, then the ``jobs`` stream) until ``done(record)`` or its
    state is final; raise its typed error if it failed."""
    sub = client.subscribe("supervisor", "jobs")
    try:
        end = time.monotonic() + timeout
        rec = _record(client, job_id)
        while not done(rec) and not rec.state.ended:
            if on_change:
                on_change(rec)
            left = end - time.monotonic()
            if left <= 0:
                raise ServiceUnavailable(f"print job {job_id} still {rec.state} after {timeout:g} s",
                                         timeout_s=timeout)
            try:
                msg = sub.get(timeout=min(left, 2.0))
            except queue.Empty:  # a missed message: ask once more (snapshot)
                rec = _record(client, job_id)
                continue
            if msg.job_id == job_id:
                rec = msg
        if rec.state == PrintJob.FAILED and rec.error is not None:
            raise error_from_code(rec.error.code, rec.error.message, rec.error.details)
        return rec
    finally:
        sub.close()


def _record(client: Caller, job_id: str) -> s.JobRecord:
    rec: s.JobRecord = client.call("supervisor", "job", s.JobQuery(job_id=job_id))
    return rec
