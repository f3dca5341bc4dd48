"""Messages posted up to the console (small dataclasses; attributes down, messages up).

The cell link posts what the cell says (telemetry, liveliness, health, programs, job lists); the screens post
what the operator asks for (a client call, a job printed again) and what they learned (a job removed). The
console handles every one of them (``@on``); no screen calls the console's own methods."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

from textual.message import Message
from textual.notifications import SeverityLevel

if TYPE_CHECKING:
    from fabric import schemas as s
    from fabric.client import Client

__all__ = ["Telemetry", "Liveliness", "HealthReport", "Reply", "ProgramReady", "CollisionChecked", "LimitsReady",
           "JobsListed", "CellsListed", "CallRequested", "JobRemoved", "ReprintRequested"]


# --- from the cell link -------------------------------------------------------------------

@dataclass
class Telemetry(Message):
    """One decoded message of ``topic`` (pose, extrusion, temps, state, events, jobs, queue) from cell ``cell``."""

    cell: str
    topic: str
    payload: Any


@dataclass
class Liveliness(Message):
    """Which services of cell ``cell`` are alive (a full answer, or one change)."""

    cell: str
    alive: dict[str, bool]


@dataclass
class HealthReport(Message):
    """How the services of cell ``cell`` that answered are: service -> the reasons it is degraded ([] = ok)."""

    cell: str
    degraded: dict[str, list[str]]


@dataclass
class ProgramReady(Message):
    """The loaded program's toolpath (``toolpath`` None: no program, or it could not be read)."""

    cell: str
    program_id: str
    toolpath: Any


@dataclass
class CollisionChecked(Message):
    """The station's collision report on the program ``program_id`` of cell ``cell`` (the one loaded when the
    check was asked for; "" when the console did not know it yet)."""

    cell: str
    program_id: str
    report: Any


@dataclass
class LimitsReady(Message):
    """Joint names and limits (degrees) of cell ``cell``'s arm, and where they come from (``station``: the
    station of that cell told them; ``model``: the console's own ``--cell-config``)."""

    cell: str
    names: list[str]
    lower_deg: list[float]
    upper_deg: list[float]
    source: str


@dataclass
class JobsListed(Message):
    """The supervisor's job list (queue order, then history). ``changes_seen``: how many changes of the queue
    (``supervisor/queue``) the console had taken when the list was asked for; a list asked before the latest one
    may not show it, and is asked for again."""

    cell: str
    jobs: list[Any]
    changes_seen: int = 0


@dataclass
class CellsListed(Message):
    """Cells on the fabric: name -> the services alive there."""

    cells: dict[str, list[str]]


# --- from the console's commands and screens -------------------------------------------------

@dataclass
class Reply(Message):
    """What a command answered (or why it was not asked): ``ok`` and one line of text, or a longer ``report``
    to show in a dialog. Shown on the reply line of every screen and kept in the log."""

    command: str
    ok: bool
    text: str
    report: str = ""
    severity: SeverityLevel | Literal[""] = ""

    def __post_init__(self) -> None:
        super().__post_init__()
        self.severity = self.severity or ("information" if self.ok else "error")


@dataclass
class CallRequested(Message):
    """A screen asks the console to run ``call(client)`` on a worker thread with the client of the cell
    followed, and to answer it on the reply line under ``label``. ``refresh_jobs``: read the job list after
    (the ``jobs`` stream carries changed records, not removed ones)."""

    label: str
    call: Callable[[Client], Any]
    refresh_jobs: bool = False


@dataclass
class JobRemoved(Message):
    """The supervisor removed job ``job_id``: it leaves the screens at once (the list read next confirms it)."""

    job_id: str


@dataclass
class ReprintRequested(Message):
    """Print a job's file again, as a new job with its settings."""

    record: s.JobRecord
