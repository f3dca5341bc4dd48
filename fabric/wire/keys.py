"""Every key expression of the fabric, declared once: builders, parsers and the endpoint table.

Layout (``<cell>`` lets several cells share one Zenoh fabric)::

    am/<cell>/alive/<service>                 liveliness token of each service
    am/<cell>/<service>/cmd/<command>         queryable per command (ENDPOINTS)
    am/<cell>/<service>/artifact/<sha256>     content-addressed results (G-code, programs)
    am/<cell>/station/{pose,extrusion,state,temps,events}   station telemetry
    am/<cell>/<service>/progress              job progress (slicer, planner)
    am/<cell>/supervisor/jobs                 print job records, on every change
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from fabric import schemas as s

__all__ = ["ROOT", "SERVICES", "TOPICS", "Endpoint", "ENDPOINTS", "endpoints_of", "Keys", "valid_cell", "parse_alive",
           "ALIVE_EVERY_CELL", "EVERY_KEY", "CELL_PATTERN", "ArtifactSource", "ARTIFACT_SOURCES",
           "ARTIFACT_TIMEOUT_S"]

ROOT = "am"
SERVICES = ("station", "slicer", "planner", "collision", "supervisor")
CELL_PATTERN = r"^[A-Za-z0-9_\-]{1,64}$"
"""What a cell name matches (it is a chunk of every key)."""
_CELL_RE = re.compile(CELL_PATTERN)

# Telemetry topics: (service, topic) -> payload type.
TOPICS: dict[tuple[str, str], type[Any]] = {
    ("station", "pose"): s.Pose,
    ("station", "extrusion"): s.Extrusion,
    ("station", "state"): s.StationState,
    ("station", "temps"): s.Temps,
    ("station", "events"): s.Event,
    ("station", "deviation"): s.Deviation,
    ("slicer", "progress"): s.JobStatus,
    ("planner", "progress"): s.JobStatus,
    ("supervisor", "jobs"): s.JobRecord,
    ("supervisor", "queue"): s.QueueChange,
}


@dataclass(frozen=True)
class Endpoint:
    """One queryable: who serves it, what it takes and returns, how long a caller waits.

    ``bulk``: its request or reply can carry megabytes (models, G-code, exports, meshes); it travels at
    data priority, batched. Every other command is interactive: sent and answered ahead of telemetry,
    unbatched (see ``fabric.client`` and ``fabric.server.service``)."""
    service: str
    command: str
    request: type[Any]
    reply: type[Any]
    timeout_s: float = 5.0
    doc: str = ""
    bulk: bool = False


def _ep(service: str, command: str, req: type, rep: type, timeout_s: float = 5.0, doc: str = "",
        bulk: bool = False) -> Endpoint:
    return Endpoint(service, command, req, rep, timeout_s, doc, bulk)


_TABLE = [
    # station: the paper's commands
    _ep("station", "position", s.Empty, s.Pose, doc="TCP pose and joints now"),
    _ep("station", "cell", s.Empty, s.CellInfo, doc="the cell it runs: its name, the arm, the joints' limits"),
    _ep("station", "home", s.Empty, s.Ack, 30.0, "collision-checked joint move to home"),
    _ep("station", "jog", s.JogRequest, s.Ack, 30.0, "collision-checked straight move of the nozzle by hand"),
    _ep("station", "extrude", s.ExtrudeRequest, s.Ack, doc="push or pull filament by hand (a hot nozzle)"),
    _ep("station", "load", s.LoadRequest, s.TimeInfo, 60.0, "load a planned program by id"),
    _ep("station", "start", s.StartRequest, s.Ack, 120.0,
        "run the loaded program (at a layer: the move there and the rest of the print certified on the part first)"),
    _ep("station", "pause", s.Empty, s.Ack, doc="controlled pause: extruder off, retract, lift"),
    _ep("station", "resume", s.StartRequest, s.Ack, doc="return to the paused spot and go on"),
    _ep("station", "recover", s.StartRequest, s.Ack, 120.0,
        "back to an interrupted print's spot and go on (the move and the rest of the print certified first)"),
    _ep("station", "stop", s.Empty, s.Ack, doc="abort safely, keep the deposit record"),
    _ep("station", "clear_plate", s.Empty, s.Ack,
        doc="the operator took the part off: the plate is clear (a print from the start needs it)"),
    _ep("station", "collisions", s.Empty, s.CollisionReport, 120.0, "sweep the loaded program"),
    _ep("station", "calibrate", s.Empty, s.CalibrationReport, 30.0, "probe the plate, fit the work object"),
    _ep("station", "ready", s.Empty, s.ReadyReport, 120.0, "checklist with pass/fail per item"),
    _ep("station", "time", s.Empty, s.TimeInfo, doc="elapsed, total and remaining simulated time"),
    _ep("station", "state", s.Empty, s.StationState, doc="state snapshot"),
    _ep("station", "events", s.EventsQuery, s.EventList, doc="event history since a sequence number"),
    _ep("station", "overrides", s.Overrides, s.StationState, doc="speed/flow/temperature overrides"),
    _ep("station", "rtf", s.StartRequest, s.StationState, doc="change the simulation's real-time factor live"),
    _ep("station", "mesh", s.MeshRequest, s.Artifact, 60.0, "as-printed part as STL or GLB, or its beads as CSV",
        bulk=True),
    _ep("station", "beads", s.BeadsQuery, s.Beads, 30.0,
        "a page of the beads the twin has laid (the part on the plate), for collision checks", bulk=True),
    # slicer
    _ep("slicer", "slice", s.SliceRequest, s.JobAccepted, 10.0, "start slicing a model (a job)", bulk=True),
    _ep("slicer", "job", s.JobQuery, s.JobStatus, doc="a slicing job's status"),
    _ep("slicer", "cancel", s.JobCancel, s.JobStatus,
        doc="cancel a slicing job (queued: it never runs; running: it stops at its next step and fails)"),
    _ep("slicer", "result", s.ArtifactQuery, s.SliceResult, doc="summary of a slicing result by G-code id"),
    _ep("slicer", "backends", s.Empty, s.Backends, doc="installed back-ends and profiles"),
    _ep("slicer", "upload", s.UploadChunk, s.UploadStatus, 30.0, "a large model, in chunks assembled on disk",
        bulk=True),
    # planner
    _ep("planner", "plan", s.PlanRequest, s.JobAccepted, 30.0, "start planning G-code (a job)", bulk=True),
    _ep("planner", "job", s.JobQuery, s.JobStatus, doc="a planning job's status"),
    _ep("planner", "cancel", s.JobCancel, s.JobStatus,
        doc="cancel a planning job (queued: it never runs; running: it stops at its next step and fails)"),
    _ep("planner", "summary", s.ArtifactQuery, s.PlanSummary, doc="summary of a planned program"),
    _ep("planner", "upload", s.UploadChunk, s.UploadStatus, 30.0, "large G-code, in chunks assembled on disk",
        bulk=True),
    _ep("planner", "export", s.ExportRequest, s.Artifact, 300.0, "RAPID / KRL / URScript / CSV", bulk=True),
    _ep("planner", "export_chunk", s.ExportChunkRequest, s.ExportChunk, 120.0,
        "an export streamed in bounded chunks, read in order from offset 0", bulk=True),
    # collision
    _ep("collision", "check", s.CollisionRequest, s.CollisionReport, 300.0, "sweep a program or a move"),
    # artifacts a print job needs are pinned where they live (never evicted while it needs them)
    _ep("slicer", "pin", s.PinRequest, s.Ack, doc="pin an artifact for a job, or release the job's pins"),
    _ep("planner", "pin", s.PinRequest, s.Ack, doc="pin an artifact for a job, or release the job's pins"),
    # supervisor
    _ep("supervisor", "status", s.Empty, s.FabricStatus, doc="services alive and the current job"),
    _ep("supervisor", "submit", s.JobSubmit, s.JobAccepted, 30.0,
        "queue a print job: slice -> plan -> check -> load (-> start)", bulk=True),
    _ep("supervisor", "upload", s.UploadChunk, s.UploadStatus, 30.0,
        "a large file to submit (JobSubmit.upload_id), in chunks assembled on disk", bulk=True),
    _ep("supervisor", "job", s.JobQuery, s.JobRecord, doc="one print job's whole record"),
    _ep("supervisor", "jobs", s.JobsQuery, s.JobList, doc="a page of the print jobs: the queue and the history"),
    _ep("supervisor", "job_remove", s.JobQuery, s.Ack, doc="remove a job that is not on the station"),
    _ep("supervisor", "job_move", s.JobMove, s.JobList, doc="reorder the waiting queue"),
    _ep("supervisor", "job_next", s.Empty, s.Ack, 60.0,
        "the plate is clear: load the next prepared job, started if it was submitted with start"),
    _ep("supervisor", "files", s.FilesQuery, s.FileList, doc="a page of the file library, most recently used first"),
    _ep("supervisor", "file", s.FileQuery, s.LibraryFile, doc="one library file (by its id or a unique start of it)"),
    _ep("supervisor", "file_add", s.FileAdd, s.LibraryFile, 60.0, "keep a model or G-code file in the library",
        bulk=True),
    _ep("supervisor", "file_remove", s.FileQuery, s.Ack, doc="forget a library file"),
]
# every service answers for its own health (served by the runtime, fabric.server.service)
_TABLE += [_ep(svc, "health", s.Empty, s.Health, 2.0, "ok, or degraded with the reasons") for svc in SERVICES]
ENDPOINTS: dict[tuple[str, str], Endpoint] = {(e.service, e.command): e for e in _TABLE}

ARTIFACT_TIMEOUT_S = 60.0
"""How long a caller waits for the reply to an artifact query (a program's artifact can be a hundred MiB)."""


@dataclass(frozen=True)
class ArtifactSource:
    """A service that keeps content-addressed artifacts: a query on ``am/<cell>/<service>/artifact/<id>`` with no
    payload is answered with ``common.Artifact`` (or a ``not_found`` error) within ``timeout_s``, at bulk QoS.
    Every service serves the key; these are the ones that keep artifacts (the others answer ``not_found``)."""
    service: str
    media_types: tuple[str, ...]    # what its artifacts hold (``common.Artifact.media_type``)
    doc: str                        # which artifacts, and where their ids come from
    timeout_s: float = ARTIFACT_TIMEOUT_S
    bulk: bool = True               # travels at data priority, batched, as bulk commands do
    reply: type[Any] = s.Artifact   # what answers the query


ARTIFACT_SOURCES: dict[str, ArtifactSource] = {a.service: a for a in (
    ArtifactSource("slicer", ("text/x-gcode",),
                   "a G-code by its id: a slicing job's result_id, SliceResult.gcode_id, JobRecord.gcode_id"),
    ArtifactSource("planner", ("application/x-am-fabric-program+msgpack",),
                   "a program by its id: a planning job's result_id, PlanSummary.program_id, JobRecord.program_id"),
    ArtifactSource("supervisor", ("application/octet-stream", "text/x-gcode"),
                   "a submitted file (a model, or G-code) by its id: JobRecord.model_id, LibraryFile.content_id"),
    ArtifactSource("station", ("application/x-am-fabric-program+msgpack",), "a program it loaded, by its id"),
)}
"""service -> the artifacts it keeps."""


def endpoints_of(service: str) -> list[Endpoint]:
    """The endpoints ``service`` serves, in table order (its handlers are derived from these)."""
    if service not in SERVICES:
        raise KeyError(f"no service {service!r}; services: {', '.join(SERVICES)}")
    return [e for e in _TABLE if e.service == service]


def valid_cell(cell: str) -> str:
    if not _CELL_RE.match(cell):
        raise ValueError(f"cell name {cell!r} must match {CELL_PATTERN}")
    return cell


class Keys:
    """Key builders for one cell."""

    def __init__(self, cell: str) -> None:
        self.cell = valid_cell(cell)
        self.prefix = f"{ROOT}/{cell}"

    @classmethod
    def every_cell(cls) -> Keys:
        """Key expressions that match every cell (``am/*/...``): access-control rules, fabric-wide listings."""
        keys = cls.__new__(cls)
        keys.cell, keys.prefix = "*", f"{ROOT}/*"
        return keys

    def alive(self, service: str) -> str:
        return f"{self.prefix}/alive/{service}"

    def alive_all(self) -> str:
        return f"{self.prefix}/alive/*"

    def cmd(self, service: str, command: str) -> str:
        return f"{self.prefix}/{service}/cmd/{command}"

    def health_all(self) -> str:
        """The health queryable of every service of the cell (one query, one reply each)."""
        return f"{self.prefix}/*/cmd/health"

    def cmd_all(self, service: str) -> str:
        """Every command queryable of ``service``."""
        return f"{self.prefix}/{service}/cmd/*"

    def topic(self, service: str, topic: str) -> str:
        if (service, topic) not in TOPICS:
            raise KeyError(f"no topic {service}/{topic}")
        return f"{self.prefix}/{service}/{topic}"

    def artifact(self, service: str, artifact_id: str) -> str:
        return f"{self.prefix}/{service}/artifact/{artifact_id}"

    def artifact_all(self, service: str) -> str:
        return f"{self.prefix}/{service}/artifact/*"

    def parse_artifact(self, key: str) -> str:
        """The artifact id of an artifact key (the last chunk after ``/artifact/``)."""
        _, sep, tail = key.rpartition("/artifact/")
        if not sep or "/" in tail:
            raise ValueError(f"not an artifact key: {key}")
        return tail


EVERY_KEY = f"{ROOT}/**"
"""Every key of the fabric, of every cell."""

ALIVE_EVERY_CELL = f"{ROOT}/*/alive/*"
"""Every liveliness token of every cell on the fabric (to list the cells present)."""


def parse_alive(key: str) -> tuple[str, str]:
    """``am/<cell>/alive/<service>`` -> (cell, service)."""
    m = re.fullmatch(rf"{ROOT}/([^/]+)/alive/([^/]+)", key)
    if not m:
        raise ValueError(f"not a liveliness key: {key}")
    return m.group(1), m.group(2)
