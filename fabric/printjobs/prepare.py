"""Preparing a print job: slice (unless it is G-code), plan, check collisions; each stage survives a
restart of the service it calls.

Every stage calls the owning service over the fabric and waits for its job.
A stage whose service is gone (``unavailable``) or restarted and forgot the
job (``not_found``) is retried from its start with a growing pause, within a
budget: the launcher restarts dead services, and results are content-addressed
and kept on disk, so a retried stage ends with the same artifact. Any other
typed error (a broken mesh, an unreachable target, a move extruding below the
material's minimum temperature, a collision) fails the job with that error.

A job that fails (its stage's time ran out, say) or is removed while it is
prepared cancels the slicing or planning job it started (``<service>/cmd/cancel``):
the slicer went on for minutes slicing a part whose job had failed. A removal
stops the wait at once (:meth:`Preparer.stop`), not when the stage ends.
"""
from __future__ import annotations

import itertools
import logging
import threading
import time
from collections.abc import Callable

from fabric import schemas as s
from fabric.client import Client
from fabric.schemas.states import PrintJob
from fabric.store.artifacts import ArtifactStore
from fabric.wire.errors import (
    ColdExtrusionError,
    CollisionError,
    FabricError,
    NotFound,
    ServiceUnavailable,
    UnreachableError,
)

__all__ = ["Preparer", "PrepareCancelled", "RETRY_BUDGET_S"]

log = logging.getLogger("fabric.printjobs")
RETRY_BUDGET_S = 180.0
_PAUSES_S = (0.25, 0.5, 1.0, 2.0, 4.0)


class PrepareCancelled(Exception):
    """The job was removed (or the supervisor is closing) while it was being prepared."""


class Preparer:
    """Runs the preparation stages of one job at a time (see the module docstring)."""

    def __init__(self, client: Client, models: ArtifactStore, save: Callable[[s.JobRecord], None],
                 closed: threading.Event, budget_s: float = RETRY_BUDGET_S) -> None:
        self.client = client
        self.models = models
        self.save = save
        self.closed = closed
        self.budget_s = budget_s
        self._lock = threading.Lock()
        self._current = ""                          # the job being prepared
        self._halt = threading.Event()              # set: stop preparing it (removed, or the supervisor closes)
        self._started: tuple[str, str] | None = None    # (service, job id) of the slicing or planning job under way

    def stop(self, job_id: str | None = None) -> None:
        """Stop preparing ``job_id`` (None: whatever is prepared) within a quarter of a second: it was removed, or
        the supervisor closes. The preparation ends with :class:`PrepareCancelled`."""
        with self._lock:
            if job_id is None or job_id == self._current:
                self._halt.set()

    def prepare(self, rec: s.JobRecord) -> None:
        """Slice, plan and check ``rec``: on success it is ``prepared`` (still queued); on a typed
        error it is ``failed`` with the error. Progress is saved (and published) as it goes."""
        with self._lock:
            self._current, self._halt = rec.job_id, threading.Event()
        try:
            self._prepare(rec)
        finally:
            with self._lock:
                self._current = ""

    def _prepare(self, rec: s.JobRecord) -> None:
        try:
            if rec.source == "model":
                self._stage(rec, PrintJob.SLICING, 0.0, lambda: self._slice(rec))
            self._stage(rec, PrintJob.PLANNING, 0.3, lambda: self._plan(rec))
            self._stage(rec, PrintJob.CHECKING, 0.7, lambda: self._check(rec))
        except PrepareCancelled:
            if not self.closed.is_set():
                self._cancel_started(rec, f"print job {rec.job_id} was removed")
            raise
        except FabricError as err:
            self._cancel_started(rec, f"print job {rec.job_id} failed: {err.message}")
            wire = err.to_wire()
            rec.state, rec.reason = PrintJob.FAILED, f"{err.code}: {err.message}"
            rec.error = s.ErrorReply(code=wire["code"], message=wire["message"], details=wire["details"])
            rec.stage, rec.ended_s = "failed", time.time()
            log.info("job %s failed: %s", rec.job_id, rec.reason)
            self.save(rec)
            return
        rec.state, rec.prepared, rec.progress_r = PrintJob.QUEUED, True, 0.0
        rec.stage = "prepared: waiting for the station"
        self.save(rec)

    # Stages -------------------------------------------------------------------------------

    def _stage(self, rec: s.JobRecord, state: PrintJob, progress_r: float, run: Callable[[], None]) -> None:
        rec.state, rec.stage, rec.progress_r = state, state.value, progress_r
        self.save(rec)
        deadline = time.monotonic() + self.budget_s
        for attempt in itertools.count():
            self._check_halted(rec)
            try:
                run()
                return
            except (ServiceUnavailable, NotFound) as err:
                self._check_halted(rec)             # a removed job, a closing supervisor: no failure, no retry
                if time.monotonic() >= deadline:
                    raise ServiceUnavailable(f"{state} did not complete within {self.budget_s:g} s: {err.message}",
                                             timeout_s=self.budget_s) from err
                pause = _PAUSES_S[min(attempt, len(_PAUSES_S) - 1)]
                rec.stage = f"{state}: retrying ({err.code}: {err.message})"
                log.warning("job %s: %s failed (%s: %s); retrying in %.2f s", rec.job_id, state, err.code,
                            err.message, pause)
                self.save(rec)
                self._cancel_started(rec, f"print job {rec.job_id}: {state} is tried again")
                self._halt.wait(pause)

    def _check_halted(self, rec: s.JobRecord) -> None:
        if self._halt.is_set() or self.closed.is_set():
            raise PrepareCancelled(rec.job_id)

    def _wait(self, service: str, job_id: str) -> s.JobStatus:
        """Wait for the job just started at ``service`` (cancelled if the print job fails or is removed)."""
        self._started = (service, job_id)
        done = self.client.wait_job(service, job_id, timeout=self.budget_s, cancel=self._halt)
        self._started = None
        return done

    def _cancel_started(self, rec: s.JobRecord, reason: str) -> None:
        """Cancel the slicing or planning job this preparation started, if it is still under way."""
        started, self._started = self._started, None
        if started is None:
            return
        service, job_id = started
        try:
            st = self.client.cancel_job(service, job_id, reason)
            log.info("job %s: cancelled %s job %s (%s): %s", rec.job_id, service, job_id, st.state, reason)
        except FabricError as err:           # the service is gone (its job with it), or forgot the job
            log.warning("job %s: could not cancel %s job %s: %s: %s", rec.job_id, service, job_id, err.code,
                        err.message)

    def _slice(self, rec: s.JobRecord) -> None:
        model = self.models.get(rec.model_id).data
        overrides = dict(rec.overrides)
        if rec.filament_diameter_mm is not None:       # sliced for the filament the job was submitted with
            overrides["filament_diameter_mm"] = f"{rec.filament_diameter_mm:g}"
        acc = self.client.slice(s.SliceRequest(model=model, filename=rec.filename, profile=rec.profile,
                                               backend=rec.backend, overrides=overrides, layers=rec.layers))
        done = self._wait("slicer", acc.job_id)
        rec.gcode_id = done.result_id
        self.client.pin("slicer", rec.gcode_id, rec.job_id)

    def _plan(self, rec: s.JobRecord) -> None:
        station = self.client.state()      # plan against the station's current (possibly calibrated) work object
        name = rec.filename.rsplit(".", 1)[0] + ".gcode"
        gcode = self.models.get(rec.model_id).data if rec.source == "gcode" else b""
        acc = self.client.plan(s.PlanRequest(gcode=gcode, gcode_id=rec.gcode_id if not gcode else "",
                                             filename=name, wobj_xyz_mm=station.wobj_xyz_mm,
                                             wobj_rpy_deg=station.wobj_rpy_deg,
                                             filament_diameter_mm=rec.filament_diameter_mm))
        done = self._wait("planner", acc.job_id)
        summary = self.client.plan_summary(done.result_id)
        rec.program_id, rec.plan = done.result_id, summary
        self.client.pin("planner", rec.program_id, rec.job_id)
        fu = summary.first_unreachable
        if fu is not None:
            raise UnreachableError(f"the program has unreachable targets, the first at G-code line "
                                   f"{fu.gcode_line}: {fu.why()}{summary.counted()}", **fu.error_details())
        cold = summary.cold_extrusion
        if cold is not None:
            raise ColdExtrusionError(f"the program would extrude cold: {cold.message}", **{
                k: v for k, v in s.to_plain(cold).items() if k != "message"})

    def _check(self, rec: s.JobRecord) -> None:
        """The certified sweep of the program against its own beads (the one `fabric-cli check` runs); a
        hit fails the job with its G-code line, move, bodies, place and time."""
        report = self.client.check(s.CollisionRequest(program_id=rec.program_id))
        rec.collisions = report
        hit = report.first_hit
        if hit is not None:
            what = hit.message or (f"t={hit.t_s:.2f} s, G-code line {hit.gcode_line}: "
                                   f"{hit.body_a} hits {hit.body_b}")
            raise CollisionError(f"collision at {what}", **{k: v for k, v in s.to_plain(hit).items()
                                                            if k != "message"})

