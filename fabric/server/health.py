"""A service's health: ``ok``, or ``degraded`` with the reasons, and a back-off for loops that keep failing.

Health is what a service knows about itself that liveliness cannot say: it
answers, but something inside it is failing (a handler raised a bug, the
station's clock keeps failing on a full disk). Each reason belongs to a
*source* (``handler:load``, ``clock``) so the part that recovers can clear its
own reason. Health is served at ``<service>/cmd/health`` and shown by
``fabric-cli status`` and the console.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from fabric import schemas as s
from fabric.schemas import states

__all__ = ["Health", "Backoff"]


class Health:
    """The reasons a service is degraded, by source; thread-safe."""

    def __init__(self, service: str) -> None:
        self.service = service
        self._lock = threading.Lock()
        self._reasons: dict[str, tuple[str, float]] = {}     # source -> (reason, since wall s)

    def degrade(self, source: str, reason: str) -> None:
        with self._lock:
            since = self._reasons.get(source, (reason, time.time()))[1]
            self._reasons[source] = (reason, since)

    def clear(self, source: str) -> None:
        with self._lock:
            self._reasons.pop(source, None)

    @property
    def degraded(self) -> str | None:
        """The reasons in one line, or None when healthy."""
        with self._lock:
            return "; ".join(r for r, _ in self._reasons.values()) or None

    def report(self) -> s.Health:
        with self._lock:
            reasons = sorted(self._reasons.items(), key=lambda kv: kv[1][1])
        return s.Health(service=self.service, state=states.Health.DEGRADED if reasons else states.Health.OK,
                        reasons=[f"{src}: {why}" for src, (why, _) in reasons],
                        since_s=reasons[0][1][1] if reasons else 0.0)


@dataclass
class Backoff:
    """Pauses for a loop that fails again and again: ``first_s`` doubling up to ``max_s``; a run of
    ``healthy_s`` without a failure starts over (a failure a day is not a failing loop)."""

    first_s: float = 0.05
    max_s: float = 5.0
    healthy_s: float = 30.0
    failures: int = 0
    _last_failure_s: float = float("-inf")

    def failed(self) -> float:
        """Note a failure; the pause to take before trying again."""
        now = time.monotonic()
        if now - self._last_failure_s > self.healthy_s:
            self.failures = 0
        self.failures += 1
        self._last_failure_s = now
        return min(self.first_s * 2 ** (self.failures - 1), self.max_s)

    def recovered(self) -> bool:
        """Whether the loop has run ``healthy_s`` since its last failure (or never failed)."""
        return time.monotonic() - self._last_failure_s > self.healthy_s
