"""Long work as jobs: accepted at once with an id, run by one worker thread, progress published, result kept.

A service owns a :class:`JobRunner`. ``submit(kind, fn)`` returns a job id
immediately; ``fn(job)`` runs on the runner's worker thread and may call
``job.progress(fraction, stage)``; it returns the result id (an artifact id)
or raises a FabricError. Status is queryable (``<service>/cmd/job``) and
published on ``<service>/progress`` (throttled, plus every state change).

``cancel(job_id, reason)`` (``<service>/cmd/cancel``): a queued job fails at
once and never runs; a running one fails at its next ``job.progress`` (or
``job.check()``), where :class:`JobCancelled` is raised through the work and
unwinds it (the work's own clean-up runs). An ended job stays as it was.
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
from fabric.wire.errors import FabricError, InternalError, NotFound, StateError

__all__ = ["Job", "JobRunner", "JobCancelled"]

log = logging.getLogger("fabric.server.jobs")
PROGRESS_PERIOD_S = 0.1


class JobCancelled(StateError):
    """The job was cancelled (``<service>/cmd/cancel``): raised at its next step, it fails the job so."""

    def __init__(self, job_id: str, reason: str) -> None:
        super().__init__(f"job {job_id} was cancelled" + (f": {reason}" if reason else ""), state="cancelled",
                         command="cancel", job_id=job_id, reason=reason)


class Job:
    """Handle given to the job function: report progress through it (and hear there that it was cancelled)."""

    def __init__(self, runner: JobRunner, status: JobStatus, cancel: threading.Event) -> None:
        self._runner, self.status = runner, status
        self._cancel = cancel
        self._last_pub = 0.0

    @property
    def job_id(self) -> str:
        return self.status.job_id

    def check(self) -> None:
        """Raise :class:`JobCancelled` if the job was cancelled."""
        if self._cancel.is_set():
            raise JobCancelled(self.job_id, self._runner.cancel_reason(self.job_id))

    def progress(self, fraction: float, stage: str | None = None) -> None:
        self.check()
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
        self._cancels: dict[str, tuple[threading.Event, str]] = {}     # job id -> set when cancelled, and why
        self._queue: queue.Queue = queue.Queue()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name=f"{name}:jobs", daemon=True)
        self._thread.start()

    def submit(self, kind: str, fn: Callable[[Job], str]) -> JobStatus:
        now = time.time()
        st = JobStatus(job_id=uuid.uuid4().hex[:12], kind=kind, state=states.Job.QUEUED, created_s=now, updated_s=now)
        with self._lock:
            self._jobs[st.job_id] = st
            self._cancels[st.job_id] = (threading.Event(), "")
            while len(self._jobs) > self._keep:
                gone = next(iter(self._jobs))
                self._jobs.pop(gone)
                self._cancels.pop(gone, None)
        self.publish(st)
        self._queue.put((st, fn))
        return st

    def cancel(self, job_id: str, reason: str = "") -> JobStatus:
        """Cancel a job (module docstring); its status as it is now (a queued one failed already)."""
        with self._lock:
            st = self._jobs.get(job_id)
            if st is None:
                raise NotFound(f"no {self.name} job {job_id}", job_id=job_id)
            if st.state.ended:
                return st
            event, _old = self._cancels[job_id]
            self._cancels[job_id] = (event, reason)
            event.set()
            if st.state == states.Job.QUEUED:          # it never runs (the worker passes it by)
                _fail(st, JobCancelled(job_id, reason))
        log.info("%s job %s cancelled: %s", self.name, job_id, reason or "(no reason given)")
        self.publish(st)
        return st

    def cancel_reason(self, job_id: str) -> str:
        with self._lock:
            return self._cancels.get(job_id, (None, ""))[1]

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
            with self._lock:
                if st.state.ended:                      # cancelled while it waited in the queue
                    continue
                st.state = states.Job.RUNNING
                cancel = self._cancels.setdefault(st.job_id, (threading.Event(), ""))[0]
            self.publish(st)
            try:
                job = Job(self, st, cancel)
                job.check()
                st.result_id = fn(job)
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
