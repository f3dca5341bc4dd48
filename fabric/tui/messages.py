"""Messages posted up to the console (small classes; attributes down, messages up)."""
from __future__ import annotations

from typing import Any, Literal

from textual.message import Message
from textual.notifications import SeverityLevel

__all__ = ["Telemetry", "Liveliness", "Reply", "ProgramReady", "CollisionChecked", "LimitsReady", "JobsListed",
           "CellsListed"]


class Telemetry(Message):
    """One decoded message of ``topic`` (pose, extrusion, temps, state, events, jobs) from cell ``cell``."""

    def __init__(self, cell: str, topic: str, payload: Any) -> None:
        super().__init__()
        self.cell, self.topic, self.payload = cell, topic, payload


class Liveliness(Message):
    """Which services of cell ``cell`` are alive (a full answer, or one change)."""

    def __init__(self, cell: str, alive: dict[str, bool]) -> None:
        super().__init__()
        self.cell, self.alive = cell, alive


class HealthReport(Message):
    """How the services of cell ``cell`` that answered are: service -> the reasons it is degraded ([] = ok)."""

    def __init__(self, cell: str, degraded: dict[str, list[str]]) -> None:
        super().__init__()
        self.cell, self.degraded = cell, degraded


class Reply(Message):
    """What a command answered: ``ok`` and one line of text, or a longer ``report`` to show in a dialog."""

    def __init__(self, command: str, ok: bool, text: str, report: str = "",
                 severity: SeverityLevel | Literal[""] = "") -> None:
        super().__init__()
        self.command, self.ok, self.text, self.report = command, ok, text, report
        self.severity: SeverityLevel = severity or ("information" if ok else "error")


class ProgramReady(Message):
    """The loaded program's toolpath (``toolpath`` None: no program, or it could not be read)."""

    def __init__(self, cell: str, program_id: str, toolpath: Any) -> None:
        super().__init__()
        self.cell, self.program_id, self.toolpath = cell, program_id, toolpath


class CollisionChecked(Message):
    """The station's collision report on the program ``program_id`` of cell ``cell`` (the one loaded when the
    check was asked for; "" when the console did not know it yet)."""

    def __init__(self, cell: str, program_id: str, report: Any) -> None:
        super().__init__()
        self.cell, self.program_id, self.report = cell, program_id, report


class LimitsReady(Message):
    """Joint names and limits (degrees) of cell ``cell``'s arm, and where they come from (``station``: the
    station of that cell told them; ``model``: the console's own ``--cell-config``)."""

    def __init__(self, cell: str, names: list[str], lower_deg: list[float], upper_deg: list[float],
                 source: str) -> None:
        super().__init__()
        self.cell, self.names, self.lower_deg, self.upper_deg, self.source = cell, names, lower_deg, upper_deg, source


class JobsListed(Message):
    """The supervisor's job list (queue order, then history)."""

    def __init__(self, cell: str, jobs: list[Any]) -> None:
        super().__init__()
        self.cell, self.jobs = cell, jobs


class CellsListed(Message):
    """Cells on the fabric: name -> the services alive there."""

    def __init__(self, cells: dict[str, list[str]]) -> None:
        super().__init__()
        self.cells = cells
