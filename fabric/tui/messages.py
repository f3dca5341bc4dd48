"""Messages the telemetry feed posts to the console (small dataclasses; attributes down, messages up)."""
from __future__ import annotations

from typing import Any

from textual.message import Message


class Telemetry(Message):
    """One decoded telemetry message from topic ``topic`` (pose, extrusion, temps, state, events)."""

    def __init__(self, topic: str, payload: Any) -> None:
        super().__init__()
        self.topic, self.payload = topic, payload


class Liveliness(Message):
    """Which services are alive now."""

    def __init__(self, alive: dict[str, bool]) -> None:
        super().__init__()
        self.alive = alive
