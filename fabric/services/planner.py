"""Planner service: G-code (inline or the slicer's artifact) -> verified robot program, as a job.

Results are content-addressed: the program is stored as an artifact whose id
is the sha256 of its encoded bytes, served at ``planner/artifact/<id>`` so
that the station and the collision checker fetch it over the fabric (no
shared filesystem between hosts).

The last plan stays at hand (program and CSV times), so its export starts
formatting at once, without reading the artifact back and decoding it. A plan is
written chunk by chunk to files under ``<data dir>/plans/<job id>/`` and mapped
back (:mod:`fabric.motion.program_file`): the process holds a chunk of rows at a
time, so a 500 MB G-code file plans in the memory of a small one, and walking
the program (cycle time, artifact, exports) gives its pages back as it goes. A
plan's files are removed when the next plan starts (or the service stops). The
artifact is written to the durable store by a background thread once its id
is known (the job ends with that id); until it is on disk it is served from
memory, and closing the service waits for the writes still under way. That thread runs at a
lower OS priority, so the writes give way to an export being formatted.
"""
from __future__ import annotations

import argparse
import io
import shutil
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO, cast

import numpy as np
import zenoh

from fabric import schemas as s
from fabric.client import Client
from fabric.motion.program import Program
from fabric.motion.timing import StartState, time_program
from fabric.planning import PlanOptions, plan_gcode
from fabric.planning.blas import single_blas_thread
from fabric.planning.memory import give_back_freed_memory, keep_freed_memory
from fabric.planning.post import write_export
from fabric.planning.post.stream import ExportStream
from fabric.planning.report import Reachability, target_why
from fabric.programs import content_id, program_artifact_pieces, program_from_artifact
from fabric.robot.cell import Cell
from fabric.robot.frames import xyzrpy_to_T
from fabric.schemas import states
from fabric.schemas.upload import MAX_GCODE_BYTES
from fabric.server.disk import disk_full_of, require_room
from fabric.server.jobs import Job, JobRunner
from fabric.server.service import Service
from fabric.server.uploads import UploadStore
from fabric.services.plan_handoff import PlanHandoff
from fabric.wire import codec
from fabric.wire.config import add_cell_argument, service_data_dir
from fabric.wire.errors import (
    BadRequest,
    ColdExtrusionError,
    FabricError,
    InternalError,
    NotFound,
    UnreachableError,
    error_from_code,
)

__all__ = ["PlannerService", "build", "add_arguments"]

# The allocator is tuned as this module is imported, before the service opens its session: the arena limit
# only holds for threads started after it (fabric.planning.memory)
keep_freed_memory()

MEDIA = {"rapid": "text/x-rapid", "krl": "text/x-krl", "urscript": "text/x-urscript", "csv": "text/csv"}
SUFFIX = {"rapid": "mod", "krl": "src", "urscript": "script", "csv": "csv"}
KEEP_PLANS = 1              # plans kept at hand for their exports (mapped from files: see the module doc)
MAX_EXPORT_STREAMS = 4      # streamed exports open at once (a reader that went away is dropped by the next)
KEEP_HANDOFFS = 8           # plan jobs whose exports can still be asked for by job id
JOB_EXPORT_POLL_S = 30.0    # an export by job id answers an empty chunk after this long without bytes


@dataclass
class PlannedProgram:
    """A recent plan kept in memory for its exports: the program and the time at each row (CSV ``t_s``)."""

    program: Program
    t_end_s: np.ndarray | None

# room a plan needs per byte of G-code: the program artifact and the plan's own files (the program again, its
# status, rotation and times), each ~170 bytes a row, a row per ~25 bytes of dense infill G-code
PROGRAM_PER_GCODE_BYTE = 14

class PlannerService(Service):
    name = "planner"

    def __init__(self, session: zenoh.Session, cell_id: str, cell: Cell, data_dir: Path | None = None) -> None:
        super().__init__(session, cell_id, data_dir)
        keep_freed_memory()                     # the next plan reuses the pages of the last one
        single_blas_thread()                    # no OpenBLAS worker spinning on the other core (planning.blas)
        self.cell = cell
        self.client = Client(session, cell_id)
        self.jobs = JobRunner("planner", self.publisher("progress", lossless=True), data_dir=self.data_dir)
        self.handle("plan", self.on_plan)
        self.handle("job", lambda q: self.jobs.get(q.job_id))
        self.handle("cancel", lambda q: self.jobs.cancel(q.job_id, q.reason))
        self.handle("summary", self.on_summary)
        self.handle("export", self.on_export)
        self.handle("export_chunk", self.on_export_chunk)
        self.uploads = UploadStore(self.data_dir / "uploads", MAX_GCODE_BYTES)     # large G-code, in pieces
        self.handle("upload", self.uploads.put)
        self.serve_pins()
        self.exports: dict[tuple[str, str, int], ExportStream] = {}   # streamed exports being read
        self.recent: dict[str, PlannedProgram] = {}                   # program id -> the last plans
        self.handoffs: dict[str, PlanHandoff] = {}                    # job id -> what the plan job has so far
        self._handoffs_lock = threading.Lock()
        self._storer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="planner-store")
        self.plans_dir = self.data_dir / "plans"            # each plan's program files (see the module doc)
        shutil.rmtree(self.plans_dir, ignore_errors=True)   # a planner that died left its last plan's

    def close(self) -> None:
        self.jobs.close()
        self._storer.shutdown(wait=True)
        super().close()
        shutil.rmtree(self.plans_dir, ignore_errors=True)

    def _forget_plans(self, keep: str) -> None:
        """A new plan starts: the plans before it are forgotten (exports under way keep what they hold; an
        export asked for later reads the artifact back) and their files removed."""
        self.recent.clear()
        with self._handoffs_lock:
            for k, h in self.handoffs.items():
                if k != keep and h.ended:
                    h.release()
        if self.plans_dir.exists():
            for d in self.plans_dir.iterdir():
                if d.name != keep:
                    shutil.rmtree(d, ignore_errors=True)

    def _store_program(self, program: Program, name: str) -> str:
        """Write the program to the durable store as an artifact (its id is the hash of its encoding,
        computed and written from the program's own columns, no copy of the whole); returns the id."""
        artifact_id, pieces = program_artifact_pieces(program, name=name)
        return self.artifacts.put_encoded(artifact_id, pieces)

    def on_plan(self, req: s.PlanRequest) -> s.JobAccepted:
        if not req.gcode and not req.gcode_id and not req.upload_id:
            raise BadRequest(f"no G-code to plan in {req.filename!r}: it is empty (give the G-code inline (gcode), "
                             "uploaded (upload_id) or a slicer artifact id (gcode_id))", field="gcode",
                             file=req.filename)
        size = self.uploads.path(req.upload_id).stat().st_size if req.upload_id else len(req.gcode)
        require_room(self.data_dir, PROGRAM_PER_GCODE_BYTE * size, self.name, "planning this G-code")
        wobj = None
        if req.wobj_xyz_mm is not None or req.wobj_rpy_deg is not None:
            wobj = xyzrpy_to_T(np.asarray(req.wobj_xyz_mm or [0.0, 0.0, 0.0]),
                               np.asarray(req.wobj_rpy_deg or [0.0, 0.0, 0.0]))
        options = PlanOptions(offset_mm=tuple(req.offset_mm), tilt_deg=tuple(req.tilt_deg), speed_r=req.speed_r,
                              rot_step_deg=req.rot_step_deg, wobj_T=wobj,
                              filament_diameter_mm=req.filament_diameter_mm, allow_off_plate=req.allow_off_plate,
                              max_turn_deg=req.max_turn_deg, linear_tol_mm=req.linear_tol_mm)
        st = self.jobs.submit("plan", lambda job: self._run(job, req, options))
        return s.JobAccepted(job_id=st.job_id, kind="plan")

    def _run(self, job: Job, req: s.PlanRequest, options: PlanOptions) -> str:
        data: bytes | Path = req.gcode
        if req.gcode_id:
            job.progress(0.0, "fetching G-code")
            data = self.client.artifact("slicer", req.gcode_id).data
        if req.upload_id:
            data = self.uploads.path(req.upload_id)    # read from disk in blocks while it is parsed
        job.progress(0.0, "planning")
        handoff = self._handoff(job.job_id)
        try:
            handoff.name = Path(req.filename).stem
            pid = self._plan(job, req, options, data, handoff)
        except FabricError as err:
            handoff.failed(err)
            raise
        except Exception as exc:    # a full disk or a bug: the job reports it; exports waiting on it get it too
            handoff.failed(disk_full_of(exc, self.name, self.data_dir)
                           or InternalError(f"planning failed: {type(exc).__name__}: {exc}"))
            raise
        finally:
            if req.upload_id:                    # the upload served its job: its file goes, whatever the outcome
                self.uploads.discard(req.upload_id)
            self._when_idle(finishing=job.job_id)
        handoff.finished(pid)
        return pid

    def _when_idle(self, finishing: str = "") -> None:
        """No plan running (but ``finishing``) and no export being read: what they freed goes back to the OS
        (fabric.planning.memory), so the idle planner does not keep the highest working set it ever had."""
        if self.exports:
            return
        if any(not states.Job(st.state).ended and st.job_id != finishing for st in self.jobs.all()):
            return
        give_back_freed_memory()

    def _plan(self, job: Job, req: s.PlanRequest, options: PlanOptions, data: bytes | Path,
              handoff: PlanHandoff) -> str:
        name = req.filename.rsplit(".", 1)[0] + ".program"
        storing: list[Future[str]] = []

        def program_ready(program: Program, report: Reachability) -> None:
            # the program is final: exports by job id start formatting it, and it is encoded, hashed (its
            # id) and written to the durable store while the plan goes on with the cycle time
            handoff.program_ready(program, _first_unreachable(report, program, self.cell), _cold_extrusion(report))
            storing.append(self._storer.submit(self._store_program, program, name))

        self._forget_plans(keep=job.job_id)
        result = plan_gcode(data, self.cell, options, progress=lambda fr: job.progress(fr, "planning"),
                            filename=req.filename, on_program=program_ready, program_dir=self.plans_dir / job.job_id,
                            on_times=handoff.times_so_far)
        program = result.program
        handoff.times_ready(result.t_end_s)
        # the job ends (its result is acknowledged) only once the program is on disk: a planner killed
        # after that loses nothing a job was told
        pid = storing[0].result() if storing else self._store_program(program, name)
        self.recent.pop(pid, None)
        self.recent[pid] = PlannedProgram(program, result.t_end_s)    # for its exports (CSV times computed once)
        while len(self.recent) > KEEP_PLANS:
            self.recent.pop(next(iter(self.recent)))
        rep = result.report
        first = _first_unreachable(rep, program, self.cell)
        cold = _cold_extrusion(rep)
        st = result.stats
        estimate = float(result.estimate_s) if np.isfinite(result.estimate_s) else -1.0
        summary = s.PlanSummary(
            program_id=pid, targets=int(st.targets), moves=int(st.moves), layers=int(st.layers),
            feasible_r=float(rep.feasible_r), runnable=first is None and cold is None, estimate_s=estimate,
            extruded_mm3=float(st.extruded_volume_mm3), path_mm=float(st.path_length_mm), first_unreachable=first,
            unreachable_by_reason={str(k): int(v) for k, v in rep.counts.items() if k != "ok"},
            unreachable_by_joint={str(k): int(v) for k, v in rep.by_joint.items()},
            elapsed_s=float(st.total_s), slowed_targets=0 if result.slowed_rows is None else len(result.slowed_rows),
            first_slowed=_first_slowed(result, program), allow_off_plate=req.allow_off_plate, cold_extrusion=cold,
            native_export=self.cell.native_export,
            **_material_fields(st))
        self.records.put("summary", pid, summary)
        return pid

    def _handoff(self, job_id: str) -> PlanHandoff:
        """The hand-off of a plan job (made by the job or by the first export asking for it)."""
        with self._handoffs_lock:
            handoff = self.handoffs.get(job_id)
            if handoff is None:
                handoff = self.handoffs[job_id] = PlanHandoff()
                ended = [k for k, h in self.handoffs.items() if h.ended]
                for k in ended[:-1]:
                    self.handoffs[k].release()      # memory: the exports keep only the last plan
                for k in ended[:max(len(self.handoffs) - KEEP_HANDOFFS, 0)]:
                    del self.handoffs[k]
            return handoff

    def on_summary(self, req: s.ArtifactQuery) -> s.PlanSummary:
        summary = self.records.get("summary", req.artifact_id, s.PlanSummary)
        if summary is None:
            raise NotFound(f"no planned program {req.artifact_id}", artifact_id=req.artifact_id)
        return summary

    def on_export(self, req: s.ExportRequest) -> s.Artifact:
        write, name = self._exporter(req.program_id, req.fmt, req.module_targets)
        buf = io.StringIO()
        write(buf)
        data = buf.getvalue().encode()
        return s.Artifact(artifact_id=content_id(data), name=name, media_type=MEDIA[req.fmt], data=data)

    def on_export_chunk(self, req: s.ExportChunkRequest) -> s.ExportChunk:
        """The next chunk of a streamed export: offset 0 starts it, each next offset is where the last ended."""
        if not req.program_id and not req.job_id:
            raise BadRequest("name the program (program_id) or the plan job (job_id)", field="program_id")
        key = (req.program_id or f"job:{req.job_id}", req.fmt, req.module_targets)
        stream = self.exports.get(key)
        if req.offset == 0:
            if req.program_id:
                write, name = self._exporter(req.program_id, req.fmt, req.module_targets)
            else:
                write, name = self._job_exporter(req.job_id, req.fmt, req.module_targets)
            if stream is not None:
                stream.cancel()
            stream = self.exports[key] = ExportStream(write, name)
            while len(self.exports) > MAX_EXPORT_STREAMS:        # readers that went away
                self.exports.pop(next(iter(self.exports))).cancel()
        elif stream is None:
            if req.program_id:
                self.on_summary(s.ArtifactQuery(artifact_id=req.program_id))     # NotFound for an unknown program
            else:
                self.jobs.get(req.job_id)                                       # NotFound for an unknown job
            raise BadRequest(f"no {req.fmt} export of {req.program_id or 'job ' + req.job_id} in progress: "
                             f"start it at offset 0", field="offset", value=req.offset)
        try:
            if req.program_id:
                data = stream.read_pieces(req.offset, req.limit_bytes)
            else:       # the job may still be planning: an empty chunk says "ask again"
                data = stream.read_pieces(req.offset, req.limit_bytes, JOB_EXPORT_POLL_S, empty_on_timeout=True)
        except FabricError:
            self.exports.pop(key, None)
            raise
        if stream.done:
            self.exports.pop(key, None)
            self._when_idle()
        program_id, name = req.program_id, stream.name
        if not program_id:
            handoff = self.handoffs.get(req.job_id)
            program_id = handoff.program_id if handoff is not None else ""
            name = f"{handoff.name or 'program'}.{SUFFIX[req.fmt]}" if handoff is not None else name
        # the pieces are joined once, as the reply is encoded (a chunk is up to limit_bytes, 4 MB by default);
        # the codec writes a Spliced as the bytes field it stands in for
        return s.ExportChunk(program_id=program_id, fmt=req.fmt, offset=req.offset,
                             data=cast(bytes, codec.Spliced(data)),
                             done=stream.done, name=name, media_type=MEDIA[req.fmt])

    def _job_exporter(self, job_id: str, fmt: str, module_targets: int) -> tuple[Callable[[TextIO], None], str]:
        """The writer of an export of plan job ``job_id``'s program: it waits for the program (and, for
        the CSV, its times), so it can be started as soon as the job is accepted."""
        st = self.jobs.get(job_id)                  # NotFound for an unknown job
        with self._handoffs_lock:
            handoff = self.handoffs.get(job_id)
        if handoff is None or handoff.released:     # an older job: its program by id, or its error
            if st.state == states.Job.DONE:
                return self._exporter(st.result_id, fmt, module_targets)
            if st.state == states.Job.FAILED and st.error is not None:
                raise error_from_code(st.error.code, st.error.message, st.error.details)
            handoff = self._handoff(job_id)

        def job_failed() -> FabricError | None:
            # a job that ended without handing over what the export waits for (it always should)
            st = self.jobs.get(job_id)
            if not states.Job(st.state).ended:
                return None
            if st.error is not None:
                return error_from_code(st.error.code, st.error.message, st.error.details)
            return InternalError(f"plan job {job_id} ended ({st.state}) without its program")

        def write(out: TextIO) -> None:
            program = handoff.program(fmt, job_failed)
            t_end = handoff.t_end_s(job_failed) if fmt == "csv" else None
            write_export(program, fmt, out, self.cell, module_targets=module_targets, t_end_s=t_end,
                         name=str(program.meta.get("name", "am_print")))

        return write, ""

    def _exporter(self, program_id: str, fmt: str, module_targets: int) -> tuple[Callable[[TextIO], None], str]:
        """The writer of an export (text stream -> None) and its file name; typed errors up front."""
        summary = self.on_summary(s.ArtifactQuery(artifact_id=program_id))
        fu = summary.first_unreachable
        if fu is not None and fmt != "csv":
            raise UnreachableError(f"program is not runnable: first unreachable target at G-code line "
                                   f"{fu.gcode_line} ({fu.why()})", **fu.error_details())
        cold = summary.cold_extrusion
        if cold is not None and fmt != "csv":
            raise _cold_error(cold)
        planned = self.recent.get(program_id)
        if planned is None:                         # an older plan: read its artifact back
            art = self.get_artifact(program_id)
            if art is None:
                raise NotFound(f"planned program {program_id} is no longer stored", artifact_id=program_id)
            planned = PlannedProgram(program_from_artifact(art), None)
        program = planned.program
        t_end = None
        if fmt == "csv" and summary.runnable:      # time at each target, from home, as the station runs it
            t_end = planned.t_end_s
            if t_end is None:
                start = StartState.at_joints(self.cell.robot, program.wobj, self.cell.home_q_rad)
                t_end = time_program(program, self.cell.robot, 1.0, start_state=start).t_end_s
        name = str(program.meta.get("name", "am_print"))

        def write(out: TextIO) -> None:
            write_export(program, fmt, out, self.cell, module_targets=module_targets, t_end_s=t_end, name=name)

        return write, f"{program.meta.get('name', 'program')}.{SUFFIX[fmt]}"


def _material_fields(stats) -> dict:
    """The PlanSummary fields saying which material the plan used and where it came from."""
    m = stats.material
    mass = stats.extruded_volume_mm3 * m.density_g_cm3 / 1000.0 if m.density_g_cm3 is not None else None
    return {"filament_diameter_mm": m.filament_diameter_mm, "material_source": m.source, "material": m.material or "",
            "density_g_cm3": m.density_g_cm3, "min_extrude_temp_c": m.min_extrude_temp_c, "mass_g": mass,
            "warnings": list(stats.warnings)}


def _first_unreachable(report: Reachability, program: Program, cell: Cell) -> s.UnreachableTarget | None:
    """The first unreachable target with its why: the joint at fault, its angle and limit (report.target_why)."""
    if report.first_unreachable is None:
        return None
    line, reason = report.first_unreachable
    row = int(report.first_unreachable_row)
    why = target_why(program, row, reason, cell.name, cell.robot)
    return s.UnreachableTarget(gcode_line=int(line), reason=reason, row=row, detail=why.detail, joint=why.joint,
                               value_deg=why.value_deg, limit_deg=why.limit_deg)


def _cold_extrusion(report: Reachability) -> s.ColdExtrusion | None:
    cold = report.cold
    if cold is None:
        return None
    return s.ColdExtrusion(gcode_line=cold.gcode_line, reason=cold.reason, row=cold.row, nozzle_c=cold.nozzle_c,
                           min_c=cold.min_c, set_line=cold.set_line, waited_c=cold.waited_c,
                           wait_line=cold.wait_line, message=cold.message)


def _cold_error(cold: s.ColdExtrusion) -> ColdExtrusionError:
    """The typed error of a program that would extrude cold (a controller export of it is refused)."""
    return ColdExtrusionError(f"program is not runnable: {cold.message}", **{
        k: v for k, v in s.to_plain(cold).items() if k != "message"})


def _first_slowed(result, program) -> s.SlowedMove | None:
    if result.slowed_rows is None or len(result.slowed_rows) == 0:
        return None
    row = int(result.slowed_rows[0])
    return s.SlowedMove(gcode_line=int(program.gcode_line[row]), row=row, joint=int(result.slowed_joint[0]) + 1)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_cell_argument(parser)


def build(session: zenoh.Session, cell_id: str, options: argparse.Namespace) -> PlannerService:
    cell = Cell.load_or_builtin(options.cell_config)
    return PlannerService(session, cell_id, cell, service_data_dir(options.data_dir, cell_id, "planner"))
