"""Supervisor service: tracks the services' liveliness and runs print jobs through the pipeline.

A job is the paper's one-click path made explicit: slice the model (slicer),
plan the G-code into a robot program (planner), sweep it for collisions
(collision), load it on the station, and optionally start it. Each stage
calls the owning service over the fabric, so every service may live on
another host. Stages and failures are published on ``supervisor/progress``.
"""
from __future__ import annotations

import argparse
import dataclasses
import queue
import threading
import time
from pathlib import Path

import zenoh

from fabric import schemas as s
from fabric.config import service_data_dir
from fabric.client import Client
from fabric.errors import CollisionError, UnreachableError
from fabric.jobs import Job, JobRunner
from fabric.keys import SERVICES, parse_alive
from fabric.runtime import Service

__all__ = ["SupervisorService", "build", "add_arguments"]


class SupervisorService(Service):
    name = "supervisor"

    def __init__(self, session: zenoh.Session, cell: str, data_dir: Path | None = None) -> None:
        super().__init__(session, cell, data_dir)
        self.client = Client(session, cell)
        self._alive: dict[str, float] = {}           # service -> since (wall time)
        self._alive_lock = threading.Lock()
        self._events: queue.Queue[tuple[str, str]] = queue.Queue()
        self._records: dict[str, s.JobRecord] = {}       # what each job was given and produced
        self.jobs = JobRunner("supervisor", self.publisher("progress", lossless=True))
        self.handle("status", self.on_status)
        self.handle("submit", self.on_submit)
        self.handle("job", lambda q: self.jobs.get(q.job_id))
        self.handle("jobs", self.on_jobs)

    def start(self) -> None:
        # liveliness: the callback only enqueues; a worker applies and logs
        self._live_sub = self.session.liveliness().declare_subscriber(
            self.keys.alive_all(), lambda smp: self._events.put((str(smp.kind), str(smp.key_expr))), history=True)
        threading.Thread(target=self._track, name="supervisor:liveliness", daemon=True).start()
        super().start()

    def _track(self) -> None:
        while not self.closed.is_set():
            try:
                kind, key = self._events.get(timeout=0.5)
            except queue.Empty:
                continue
            _, svc = parse_alive(key)
            with self._alive_lock:
                if kind.endswith("PUT"):
                    self._alive[svc] = time.time()
                    self.log.info("service %s is alive", svc)
                else:
                    self._alive.pop(svc, None)
                    self.log.warning("service %s is gone", svc)

    def close(self) -> None:
        super().close()
        self._live_sub.undeclare()
        self.jobs.close()

    # --- handlers -----------------------------------------------------------

    def on_status(self, _: s.Empty) -> s.FabricStatus:
        # who is alive: the hub's answer now; since when: what the liveliness subscriber tracked
        now = self.client.alive(timeout=2.0)
        now["supervisor"] = True
        with self._alive_lock:
            since = dict(self._alive)
        since.setdefault("supervisor", self.started_s)
        infos = [s.ServiceInfo(name=n, alive=now[n], since_s=since.get(n, 0.0) if now[n] else 0.0) for n in SERVICES]
        jobs = self.jobs.all()
        current = self._record(jobs[-1]) if jobs else None
        return s.FabricStatus(cell=self.keys.cell, services=infos, job=current)

    def on_submit(self, req: s.JobSubmit) -> s.JobAccepted:
        st = self.jobs.submit("print", lambda job: self._pipeline(job, req))
        self._records[st.job_id] = s.JobRecord(job_id=st.job_id, filename=req.filename, profile=req.profile,
                                               backend=req.backend, created_s=st.created_s)
        return s.JobAccepted(job_id=st.job_id, kind="print")

    def on_jobs(self, _: s.Empty) -> s.JobList:
        return s.JobList(jobs=[self._record(st) for st in self.jobs.all()])

    def _record(self, st: s.JobStatus) -> s.JobRecord:
        """A job's record with its status now (a copy: the pipeline keeps filling the original)."""
        rec = self._records.get(st.job_id) or s.JobRecord(job_id=st.job_id, filename="")
        return dataclasses.replace(rec, state=st.state, stage=st.stage, message=st.message, result_id=st.result_id)

    # --- the pipeline ---------------------------------------------------------

    def _pipeline(self, job: Job, req: s.JobSubmit) -> str:
        rec = self._records[job.job_id]
        c = self.client
        job.progress(0.0, "slicing")
        acc = c.slice(s.SliceRequest(model=req.model, filename=req.filename, profile=req.profile,
                                     backend=req.backend, overrides=req.overrides))
        sl = c.wait_job("slicer", acc.job_id, on_progress=lambda st: job.progress(0.3 * st.progress_r))
        rec.gcode_id = sl.result_id
        job.progress(0.3, "planning")
        station = c.state()          # plan against the station's current (possibly calibrated) work object
        acc = c.plan(s.PlanRequest(gcode_id=sl.result_id, filename=req.filename.rsplit(".", 1)[0] + ".gcode",
                                   wobj_xyz_mm=station.wobj_xyz_mm, wobj_rpy_deg=station.wobj_rpy_deg))
        pl = c.wait_job("planner", acc.job_id, on_progress=lambda st: job.progress(0.3 + 0.4 * st.progress_r))
        summary = c.plan_summary(pl.result_id)
        rec.program_id, rec.plan = pl.result_id, summary
        fu = summary.first_unreachable
        if fu is not None:
            raise UnreachableError(f"program has unreachable targets, first at G-code line {fu.gcode_line}: "
                                   f"{fu.reason}", gcode_line=fu.gcode_line, reason=fu.reason, row=fu.row)
        job.progress(0.7, "checking collisions")
        report = c.check(s.CollisionRequest(program_id=pl.result_id))
        rec.collisions = report
        hit = report.first_hit
        if hit is not None:
            raise CollisionError(f"collision at t={hit.t_s:.2f} s, G-code line {hit.gcode_line}: "
                                 f"{hit.body_a} hits {hit.body_b}", **s.to_plain(hit))
        job.progress(0.9, "loading")
        c.load(pl.result_id, job_id=job.job_id)
        if req.start:
            c.start(rtf=req.rtf)
            job.progress(1.0, "printing")
        else:
            job.progress(1.0, "loaded")
        return pl.result_id


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The supervisor has no options of its own."""


def build(session: zenoh.Session, cell: str, options: argparse.Namespace) -> SupervisorService:
    return SupervisorService(session, cell, service_data_dir(options.data_dir, cell, "supervisor"))
