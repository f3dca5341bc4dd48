"""All message schemas; importing this package registers every type in ``REGISTRY``."""
from fabric.schemas.base import REGISTRY, f, schema, to_plain, validate_into
from fabric.schemas.common import (Ack, Artifact, ArtifactQuery, Empty, ErrorReply, Health, JobAccepted,
                                   JobQuery, JobStatus, PinRequest)
from fabric.schemas.pipeline import (FINAL_JOB_STATES, ON_STATION_JOB_STATES, PRINT_JOB_STATES, Backends,
                                     CollisionHit, CollisionReport, CollisionRequest, ExportRequest,
                                     FabricStatus, JobList, JobMove, JobRecord, JobSubmit, PlanRequest, PlanSummary,
                                     ProgramMsg, ServiceInfo, SliceRequest, SliceResult, SlowedMove,
                                     UnreachableTarget)
from fabric.schemas.export import ExportChunk, ExportChunkRequest
from fabric.schemas.upload import UploadChunk, UploadStatus
from fabric.schemas.station import (CalibrationReport, Check, Event, EventList, EventsQuery,
                                    Extrusion, LoadRequest, MeshRequest, Overrides, Pose,
                                    ReadyReport, StartRequest, StationState, Temps, TimeInfo)

__all__ = [
    "REGISTRY", "f", "schema", "to_plain", "validate_into",
    "Ack", "Artifact", "ArtifactQuery", "Empty", "ErrorReply", "Health", "JobAccepted", "JobQuery", "JobStatus",
    "PinRequest",
    "FINAL_JOB_STATES", "ON_STATION_JOB_STATES", "PRINT_JOB_STATES",
    "Backends", "CollisionHit", "CollisionReport", "CollisionRequest", "ExportRequest", "FabricStatus", "JobList",
    "JobMove", "JobRecord", "JobSubmit", "PlanRequest", "PlanSummary", "ProgramMsg", "ServiceInfo", "SliceRequest",
    "SliceResult", "SlowedMove", "UnreachableTarget",
    "ExportChunk", "ExportChunkRequest", "UploadChunk", "UploadStatus",
    "CalibrationReport", "Check", "Event", "EventList", "EventsQuery", "Extrusion", "LoadRequest",
    "MeshRequest", "Overrides", "Pose", "ReadyReport", "StartRequest", "StationState", "Temps", "TimeInfo",
]
