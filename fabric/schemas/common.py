"""Messages shared by every service: empty requests, acks, errors, jobs and artifacts."""
from __future__ import annotations

from typing import Any

from fabric.schemas.base import f, schema

JOB_STATES = ("queued", "running", "done", "failed")


@schema("common.Empty")
class Empty:
    """A request with no arguments."""


@schema("common.Ack")
class Ack:
    """A command was carried out; ``message`` says what happened."""
    ok: bool = True
    message: str = ""
    state: str = ""


@schema("common.Error")
class ErrorReply:
    """The payload of every error reply (``reply_err``)."""
    code: str
    message: str
    details: dict[str, Any] = f(factory=dict)


@schema("common.JobAccepted")
class JobAccepted:
    """A long task was accepted; follow it with ``JobQuery`` or the progress topic."""
    job_id: str
    kind: str


@schema("common.JobQuery")
class JobQuery:
    job_id: str = f(max_len=128)


@schema("common.JobStatus", version=2)
class JobStatus:
    """State of a job; ``result_id`` names the content-addressed result once done."""
    job_id: str
    kind: str
    state: str = f(choices=JOB_STATES)
    progress_r: float = f(default=0.0, ge=0.0, le=1.0)
    stage: str = ""
    message: str = ""
    result_id: str = ""
    error: ErrorReply | None = None            # set when ``state`` is failed
    created_s: float = 0.0
    updated_s: float = 0.0


@schema("common.ArtifactQuery")
class ArtifactQuery:
    artifact_id: str = f(max_len=128)


@schema("common.PinRequest")
class PinRequest:
    """Keep an artifact from eviction while ``owner`` (a print job) needs it, or release the owner's pins."""
    owner: str = f(max_len=128)
    artifact_id: str = f(default="", max_len=128)
    pinned: bool = True


@schema("common.Artifact")
class Artifact:
    """Content-addressed bytes (``artifact_id`` = sha256 of ``data``)."""
    artifact_id: str
    name: str
    media_type: str
    data: bytes


HEALTH_STATES = ("ok", "degraded")


@schema("common.Health")
class Health:
    """A service's view of itself (``<service>/cmd/health``): ``ok``, or ``degraded`` with the reasons,
    each ``source: reason`` (``handler:load: KeyError ...``, ``clock: ...``), since ``since_s`` (wall-clock
    epoch seconds of the oldest reason; 0 when ok)."""
    service: str
    state: str = f(default="ok", choices=HEALTH_STATES)
    reasons: list[str] = f(factory=list)
    since_s: float = 0.0
