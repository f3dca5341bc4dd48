"""Slicer service: model bytes in (inline, or uploaded in pieces), G-code out, as a job; back-ends builtin,
PrusaSlicer and Slic3r."""
from __future__ import annotations

import argparse
from pathlib import Path

import zenoh

from fabric import schemas as s
from fabric.programs import content_id
from fabric.robot.cell import Cell
from fabric.schemas.upload import MAX_MODEL_BYTES
from fabric.server.disk import require_room
from fabric.server.jobs import Job, JobRunner
from fabric.server.service import Service
from fabric.server.uploads import UploadStore
from fabric.slicing import Placement, available_backends, list_profiles, load_profile, slice_model
from fabric.wire.config import add_cell_argument, service_data_dir
from fabric.wire.errors import BadRequest, NotFound

__all__ = ["SlicerService", "build", "add_arguments"]

GCODE_MEDIA_TYPE = "text/x-gcode"

GCODE_PER_MODEL_BYTE = 4        # room a slice needs: G-code and temporary files, per byte of model

class SlicerService(Service):
    name = "slicer"

    def __init__(self, session: zenoh.Session, cell_id: str, plate_size_mm: tuple[float, float],
                 build_height_mm: float, data_dir: Path | None = None, cell: Cell | None = None) -> None:
        """``cell``: the cell the slices are printed on (curved layers lean only as far as its arm holds)."""
        super().__init__(session, cell_id, data_dir)
        self.plate_size_mm, self.build_height_mm = plate_size_mm, build_height_mm
        self.cell = cell
        self.jobs = JobRunner("slicer", self.publisher("progress", lossless=True), data_dir=self.data_dir)
        self.handle("slice", self.on_slice)
        self.handle("job", lambda q: self.jobs.get(q.job_id))
        self.handle("cancel", lambda q: self.jobs.cancel(q.job_id, q.reason))
        self.handle("result", self.on_result)
        self.handle("backends", self.on_backends)
        self.uploads = UploadStore(self.data_dir / "uploads", MAX_MODEL_BYTES)     # large models, in pieces
        self.handle("upload", self.uploads.put)
        self.serve_pins()

    def close(self) -> None:
        super().close()
        self.jobs.close()

    def on_slice(self, req: s.SliceRequest) -> s.JobAccepted:
        profile = load_profile(req.profile, req.overrides)     # a bad profile fails now, not in the job
        if req.layers == "curved" and req.backend != "builtin":
            raise BadRequest(f"curved layers need the builtin back-end, not {req.backend!r}", backend=req.backend)
        size = self.uploads.path(req.upload_id).stat().st_size if req.upload_id else len(req.model)
        require_room(self.data_dir, GCODE_PER_MODEL_BYTE * size, self.name, "slicing this model")
        backends = available_backends()
        if backends.get(req.backend) is None:
            raise NotFound(f"slicer back-end '{req.backend}' is not installed on this host",
                           backend=req.backend, installed=[k for k, v in backends.items() if v])
        center = req.center_xy_mm
        placement = Placement(center_xy_mm=(center[0], center[1]) if center else None)
        st = self.jobs.submit("slice", lambda job: self._run(job, req, profile, placement))
        return s.JobAccepted(job_id=st.job_id, kind="slice")

    def _run(self, job: Job, req: s.SliceRequest, profile, placement) -> str:
        try:
            return self._slice(job, req, profile, placement)
        finally:
            if req.upload_id:                    # the upload served its job: its file goes, whatever the outcome
                self.uploads.discard(req.upload_id)

    def _slice(self, job: Job, req: s.SliceRequest, profile, placement) -> str:
        model = self.uploads.path(req.upload_id).read_bytes() if req.upload_id else req.model
        res = slice_model(model, req.filename, profile, backend=req.backend, placement=placement,
                          plate_size_mm=self.plate_size_mm, build_height_mm=self.build_height_mm,
                          progress=lambda fr: job.progress(fr, "slicing"), layers=req.layers, cell=self.cell)
        data = res.gcode.encode() if isinstance(res.gcode, str) else bytes(res.gcode)
        name = req.filename.rsplit(".", 1)[0] + ".gcode"
        gid = self.store_artifact(s.Artifact(artifact_id=content_id(data), name=name,
                                             media_type=GCODE_MEDIA_TYPE, data=data))
        result = s.SliceResult(gcode_id=gid, backend=res.backend, layers=int(res.layers),
                               extruded_mm3=float(res.extruded_mm3), filament_mm=float(res.filament_mm),
                               model_volume_mm3=float(res.model_volume_mm3), faces=int(res.faces),
                               elapsed_s=float(res.elapsed_s), warnings=list(res.warnings),
                               retractions=int(res.retractions), travel_mm=float(res.travel_mm),
                               bridge_area_mm2=float(res.bridge_area_mm2), curved=dict(res.curved))
        self.records.put("slice", gid, result)
        return gid

    def on_result(self, req: s.ArtifactQuery) -> s.SliceResult:
        result = self.records.get("slice", req.artifact_id, s.SliceResult)
        if result is None:
            raise NotFound(f"no slicing result {req.artifact_id}", artifact_id=req.artifact_id)
        return result

    def on_backends(self, _: s.Empty) -> s.Backends:
        return s.Backends(backends={k: v or "" for k, v in available_backends().items()}, profiles=list_profiles())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_cell_argument(parser, "its plate size")
    parser.add_argument("--build-height", type=float, default=250.0, help="reachable build height (mm)")


def build(session: zenoh.Session, cell_id: str, options: argparse.Namespace) -> SlicerService:
    cell = Cell.load_or_builtin(options.cell_config)
    size = (float(cell.plate_size_mm[0]), float(cell.plate_size_mm[1]))
    return SlicerService(session, cell_id, size, options.build_height,
                         service_data_dir(options.data_dir, cell_id, "slicer"), cell=cell)
