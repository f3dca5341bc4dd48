"""A stand-in for the fabric client, for console tests that need no services: it answers what the console asks,
records what it was told, and lets a test push telemetry into the console's link as a service would."""
from __future__ import annotations

import queue
import threading
from types import SimpleNamespace
from typing import Any

from fabric import schemas as s
from fabric.schemas import states
from fabric.wire.errors import NotFound, StateError
from fabric.wire.keys import SERVICES


class StubStream:
    """A subscription the test feeds (``put``) and the console's link reads (``get``)."""

    def __init__(self) -> None:
        self.q: queue.Queue[Any] = queue.Queue()

    def put(self, msg: Any) -> None:
        self.q.put(msg)

    def get(self, timeout: float | None = None) -> Any:
        return self.q.get(timeout=timeout)

    def close(self) -> None:
        pass


class StubClient:
    """One cell's client: ``jobs`` is what the supervisor holds, ``calls`` what the console asked for."""

    def __init__(self, cell: str = "cell1", jobs: list[s.JobRecord] | None = None,
                 state: s.StationState | None = None) -> None:
        self.keys = SimpleNamespace(cell=cell)
        self.session = None
        self.jobs_held = list(jobs or [])
        self.station = state or s.StationState(state="idle")
        self.calls: list[tuple[str, Any]] = []
        self.streams: dict[str, StubStream] = {}
        self.artifacts: dict[str, bytes] = {}
        self._lock = threading.Lock()

    def _called(self, name: str, arg: Any = None) -> None:
        with self._lock:
            self.calls.append((name, arg))

    def called(self, name: str) -> list[Any]:
        with self._lock:
            return [arg for n, arg in self.calls if n == name]

    # --- what the console's link asks --------------------------------------------------
    def subscribe(self, service: str, topic: str) -> StubStream:
        return self.streams.setdefault(topic, StubStream())

    def subscribe_alive(self, on_change=None) -> SimpleNamespace:
        return SimpleNamespace(close=lambda: None)

    def alive(self, timeout: float = 2.0) -> dict[str, bool]:
        return {name: True for name in SERVICES}

    def healths(self, timeout: float = 2.0) -> dict:
        return {}

    def state(self) -> s.StationState:
        return self.station

    def cell_info(self) -> s.CellInfo:
        """The station's cell: the IRB 140's joints and limits."""
        return s.CellInfo(name="irb140", joint_names=[f"joint_{k}" for k in range(1, 7)],
                          lower_deg=[-180.0, -90.0, -230.0, -200.0, -115.0, -400.0],
                          upper_deg=[180.0, 110.0, 50.0, 200.0, 115.0, 400.0])

    def artifact(self, service: str, artifact_id: str, timeout: float = 60.0) -> s.Artifact:
        if artifact_id not in self.artifacts:
            raise NotFound(f"no artifact {artifact_id} at {service}")
        return s.Artifact(artifact_id=artifact_id, name="f", media_type="x", data=self.artifacts[artifact_id])

    # --- supervisor ----------------------------------------------------------------------
    def jobs(self, offset: int = 0, limit: int = 100, states=()) -> s.JobList:
        return s.JobList(jobs=list(self.jobs_held), total=len(self.jobs_held))

    def job_remove(self, job_id: str) -> s.Ack:
        self._called("job_remove", job_id)
        self.jobs_held = [r for r in self.jobs_held if r.job_id != job_id]
        return s.Ack(ok=True, message=f"removed job {job_id}", state="")

    def job_next(self) -> s.Ack:
        self._called("job_next")
        return s.Ack(ok=True, message="plate marked clear", state="")

    def backends(self) -> s.Backends:
        return s.Backends(backends={"builtin": "1.0"}, profiles=["taz-pla-medium", "robot-1.2mm"])

    def submit(self, req: s.JobSubmit) -> s.JobAccepted:
        self._called("submit", req)
        return s.JobAccepted(job_id="0123456789ab", kind="print")

    # --- station -----------------------------------------------------------------------
    def home(self) -> s.Ack:
        self._called("home")
        if states.Station(self.station.state).in_print:
            raise StateError(f"cannot go home while {self.station.state}; stop first", state=self.station.state)
        return s.Ack(ok=True, message="moving home", state="idle")

    def stop(self) -> s.Ack:
        self._called("stop")
        return s.Ack(ok=True, message="stopped", state="stopped")

    def overrides(self, **values: float) -> s.StationState:
        self._called("overrides", values)
        return self.station

    def ready(self) -> s.ReadyReport:
        checks = [s.Check(name=f"check {i}", ok=i % 2 == 0, detail=f"detail of check {i}, a longer explanation")
                  for i in range(12)]
        return s.ReadyReport(ready=False, checks=checks)
