"""Long work as jobs: accepted at once with an id, run by one worker thread, progress published, result kept.

A service owns a :class:`JobRunner`. ``submit(kind, fn)`` returns a job id
immediately; ``fn(job)`` runs on the runner's worker thread and may call
``job.progress(fraction, stage)``; it returns the result id (an artifact id)
or raises a FabricError. Status is queryable (``<service>/cmd/job``) and
published on ``<service>/progress`` (throttled, plus every state change).
"""
from __future__ import annotations

import logging
import queue
import threading
import time
import traceback
import uuid
from collections.abc import Callable
from pathlib import Path

from fabric.schemas import ErrorReply, JobStatus, states
from fabric.server.disk import disk_full_of
from fabric.server.service import Publisher
from fabric.wire.errors import FabricError, InternalError, NotFound

__all__ = ["Job", "JobRunner"]

log = logging.getLogger("fabric.server.jobs")
PROGRESS_PERIOD_S = 0.1


class Job:
    """Handle given to the job function: report progress through it."""

    def __init__(self, runner: JobRunner, status: JobStatus) -> None:
        self._runner, self.status = runner, status
        self._last_pub = 0.0

    @property
    def job_id(self) -> str:
        return self.status.job_id

    def progress(self, fraction: float, stage: str | None = None) -> None:
        self.status.progress_r = min(max(float(fraction), 0.0), 1.0)
        changed = stage is not None and stage != self.status.stage
        if stage is not None:
            self.status.stage = stage
        now = time.monotonic()
        if changed or now - self._last_pub >= PROGRESS_PERIOD_S:
            self._last_pub = now
            self._runner.publish(self.status)


class JobRunner:
    """One worker thread running jobs in submission order; keeps the last ``keep`` statuses."""

    def __init__(self, name: str, publisher: Publisher | None, keep: int = 200,
                 data_dir: str | Path | None = None) -> None:
        """``data_dir``: where the jobs write (named in a ``disk_full`` error)."""
        self.name, self._pub, self._keep = name, publisher, keep
        self.data_dir = data_dir
        self._jobs: dict[str, JobStatus] = {}
        self._queue: queue.Queue = queue.Queue()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name=f"{name}:jobs", daemon=True)
        self._thread.start()

    def submit(self, kind: str, fn: Callable[[Job], str]) -> JobStatus:
        now = time.time()
        st = JobStatus(job_id=uuid.uuid4().hex[:12], kind=kind, state=states.Job.QUEUED, created_s=now, updated_s=now)
        with self._lock:
            self._jobs[st.job_id] = st
            while len(self._jobs) > self._keep:
                self._jobs.pop(next(iter(self._jobs)))
        self.publish(st)
        self._queue.put((st, fn))
        return st

    def get(self, job_id: str) -> JobStatus:
        with self._lock:
            st = self._jobs.get(job_id)
        if st is None:
            raise NotFound(f"no {self.name} job {job_id}", job_id=job_id)
        return st

    def all(self) -> list[JobStatus]:
        with self._lock:
            return list(self._jobs.values())

    def publish(self, st: JobStatus) -> None:
        st.updated_s = time.time()
        if self._pub is not None:
            self._pub.send(st)

    def close(self) -> None:
        self._queue.put(None)
        self._thread.join(timeout=2.0)

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            st, fn = item
            st.state = states.Job.RUNNING
            self.publish(st)
            try:
                st.result_id = fn(Job(self, st))
                st.state, st.progress_r = states.Job.DONE, 1.0
            except FabricError as err:
                _fail(st, err)
            except Exception as exc:  # noqa: BLE001 - a full disk, or a bug (traced): fail the job, keep running
                full = disk_full_of(exc, self.name, self.data_dir or ".")
                if full is not None:
                    log.error("%s job %s: %s", self.name, st.job_id, full.message)
                    _fail(st, full)
                else:
                    log.error("%s job %s failed:\n%s", self.name, st.job_id, traceback.format_exc())
                    _fail(st, InternalError(f"{type(exc).__name__}: {exc}"))
            self.publish(st)


def _fail(st: JobStatus, err: FabricError) -> None:
    """Mark the job failed with the error a caller gets back (``Client.wait_job`` raises it)."""
    st.state, st.message = states.Job.FAILED, err.message
    st.error = ErrorReply(code=err.code, message=err.message, details=err.to_wire()["details"])
