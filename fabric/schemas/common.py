"""Messages shared by every service: empty requests, acks, errors, jobs and artifacts."""
from __future__ import annotations

from typing import Any

from fabric.schemas import states
from fabric.schemas.base import f, schema


@schema("common.Empty")
class Empty:
    """A request with no arguments: the map ``{"_t": "common.Empty", "_v": 1}`` and nothing else.

    A service also takes it for any request whose fields all have defaults (each field then at its
    default), so a command that grows optional arguments keeps answering clients that send it."""


@schema("common.Ack")
class Ack:
    """A command was carried out; ``message`` says what happened."""
    ok: bool = True                 # always true in a reply (a refusal is an error reply instead)
    message: str = ""               # what happened, in a sentence for people
    state: str = ""                 # the station's state after a station command; the job's state after a job
                                    # command ("" when there is none)


@schema("common.Error")
class ErrorReply:
    """The payload of every error reply (``reply_err``): a stable code, a message and details to act on."""
    code: str                       # the error's kind, one of the codes listed under "Errors" (e.g. ``state``)
    message: str                    # what went wrong and what to do, in a sentence for people
    details: dict[str, Any] = f(factory=dict)   # plain values a caller can act on, by code (see "Errors")


@schema("common.JobAccepted")
class JobAccepted:
    """A long task was accepted; follow it with ``JobQuery`` (``<service>/cmd/job``) or the progress topic.

    A print job (``supervisor/submit``) is followed with ``supervisor/cmd/job`` (a ``supervisor.JobRecord``)
    and the ``supervisor/jobs`` topic instead: the supervisor publishes no ``progress``."""
    job_id: str                     # the job's id, unique on its service (12 hex digits)
    kind: str                       # ``slice``, ``plan`` or ``print``


@schema("common.JobQuery")
class JobQuery:
    """Names one job (of the service asked) by its id."""
    job_id: str = f(max_len=128)    # the id from ``common.JobAccepted``


@schema("common.JobCancel")
class JobCancel:
    """Cancel one job (of the service asked): queued, it never runs; running, it stops at its next step. Either
    way it fails with a ``state`` error that says it was cancelled and ``reason``; an ended job stays as it was.
    The supervisor cancels the slicing and planning jobs of a print job that failed or was removed."""
    job_id: str = f(max_len=128)    # the id from ``common.JobAccepted``
    reason: str = f(default="", max_len=1024)   # why, in words (the job's error says it)


@schema("common.JobStatus", version=2)
class JobStatus:
    """State of a slicing or planning job; ``result_id`` names the content-addressed result once done.

    A service keeps the statuses of its last 200 jobs in memory (a restarted service knows none of them)."""
    job_id: str                     # the job's id
    kind: str                       # ``slice`` or ``plan``
    state: states.Job                           # queued -> running -> done | failed
    progress_r: float = f(default=0.0, ge=0.0, le=1.0)   # share of the work done (1 when done)
    stage: str = ""                 # what it is doing now, in words
    message: str = ""               # a remark on the result (may be empty)
    result_id: str = ""             # once done: the artifact id of the result (slice: the G-code's ``gcode_id``;
                                    # plan: the program's ``program_id``)
    error: ErrorReply | None = None            # set when ``state`` is failed: the typed error
    created_s: float = 0.0          # when it was accepted (wall clock, epoch seconds)
    updated_s: float = 0.0          # when this status was last changed (wall clock, epoch seconds)


@schema("common.ArtifactQuery")
class ArtifactQuery:
    """Names one content-addressed artifact by its id."""
    artifact_id: str = f(max_len=128)   # sha256 of the artifact's bytes, 64 lowercase hex digits


@schema("common.PinRequest")
class PinRequest:
    """Keep an artifact from eviction while ``owner`` (a print job) needs it, or release the owner's pins."""
    owner: str = f(max_len=128)     # who needs it: a print job's id
    artifact_id: str = f(default="", max_len=128)   # the artifact to pin (ignored when releasing)
    pinned: bool = True             # true: pin ``artifact_id`` for ``owner``; false: release every pin of ``owner``


@schema("common.Artifact")
class Artifact:
    """Content-addressed bytes (``artifact_id`` = sha256 of ``data``).

    Fetched by a query on ``am/<cell>/<service>/artifact/<artifact_id>`` (no payload), or returned by a
    command (``station/mesh``, ``planner/export``). Media types: ``text/x-gcode`` (G-code),
    ``application/x-am-fabric-program+msgpack`` (a program: ``data`` is an encoded ``planner.ProgramMsg``),
    ``model/stl``, ``model/gltf-binary``, ``text/csv``, ``application/octet-stream`` (a submitted model), and
    the export formats' own."""
    artifact_id: str                # sha256 of ``data``, 64 lowercase hex digits
    name: str                       # a file name for it (e.g. ``part.gcode``, ``as-printed.stl``)
    media_type: str                 # what ``data`` holds (see above)
    data: bytes                     # the content




@schema("common.Health")
class Health:
    """A service's view of itself (``<service>/cmd/health``): ``ok``, or ``degraded`` with the reasons,
    each ``source: reason`` (``handler:load: KeyError ...``, ``clock: ...``), since ``since_s`` (wall-clock
    epoch seconds of the oldest reason; 0 when ok)."""
    service: str                    # the service answering: station, slicer, planner, collision or supervisor
    state: states.Health = f(default=states.Health.OK)   # ``ok``, or ``degraded``: it serves, but something failed
    reasons: list[str] = f(factory=list)    # each ``source: reason``, oldest first (empty when ok)
    since_s: float = 0.0            # degraded since (wall clock, epoch seconds; 0 when ok)
