"""A plan job's program and CSV times, handed to exports of that job as soon as each exists.

An export asked for by job id (``ExportChunkRequest.job_id``) starts formatting
the moment the program is final: RAPID, KRL and URScript need only the joints,
so they are written while the planner still computes the cycle time and the
program's id (the sha256 of its encoded bytes); the CSV's ``t_s`` column waits
for the times. A job that fails hands its error to the exports waiting on it.
"""
from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np

from fabric import schemas as s
from fabric.motion.program import Program
from fabric.wire.errors import ColdExtrusionError, FabricError, UnreachableError

__all__ = ["PlanHandoff", "TimesSoFar"]

CHECK_S = 1.0       # how often a waiting export asks whether the job ended without telling (a bug)


class PlanHandoff:
    """What one plan job has produced so far; exports of the job wait here for what they need."""

    def __init__(self) -> None:
        self.name = ""                                  # the program's name (the G-code file's stem), set by the job
        self.program_id = ""                            # known once the job has ended
        self._cond = threading.Condition()
        self._program: Program | None = None
        self._unreachable: s.UnreachableTarget | None = None
        self._cold: s.ColdExtrusion | None = None
        self._timed = False
        self._t_end_s: np.ndarray | None = None
        self._timed_rows = -1                           # rows whose times are known while they are computed
        self._error: FabricError | None = None
        self.released = False                           # the program forgotten: export it by its id

    @property
    def ended(self) -> bool:
        with self._cond:
            return self._error is not None or bool(self.program_id)

    def program_ready(self, program: Program, unreachable: s.UnreachableTarget | None,
                      cold: s.ColdExtrusion | None = None) -> None:
        with self._cond:
            self._program, self._unreachable, self._cold = program, unreachable, cold
            self._cond.notify_all()

    def times_ready(self, t_end_s: np.ndarray | None) -> None:
        """The time at each row (None when the program is not runnable: no times)."""
        with self._cond:
            self._timed, self._t_end_s = True, t_end_s
            self._cond.notify_all()

    def times_so_far(self, t_end_s: np.ndarray, rows: int) -> None:
        """The cycle time is being computed into ``t_end_s``: its first ``rows`` rows are known."""
        with self._cond:
            self._t_end_s, self._timed_rows = t_end_s, rows
            self._cond.notify_all()

    def finished(self, program_id: str) -> None:
        with self._cond:
            self.program_id = program_id
            self._cond.notify_all()

    def failed(self, error: FabricError) -> None:
        with self._cond:
            self._error = error
            self._cond.notify_all()

    def release(self) -> None:
        """Forget the program (an export already under way keeps its own reference)."""
        with self._cond:
            self._program = self._t_end_s = None
            self.released = True

    def _wait(self, ready: Callable[[], bool], job_failed: Callable[[], FabricError | None]) -> None:
        """Wait (holding the lock) until ``ready()`` or an error; ``job_failed()`` is asked now and then
        for the error of a job that ended without telling."""
        while not self._cond.wait_for(lambda: ready() or self._error is not None, timeout=CHECK_S):
            err = job_failed()
            if err is not None and not ready():
                self._error = err
        if not ready():
            assert self._error is not None              # the wait ended, not ready: on an error
            raise self._error

    def program(self, fmt: str, job_failed: Callable[[], FabricError | None]) -> Program:
        """The final program, once there is one; a controller format of a program that is not runnable
        (an unreachable target, a move extruding cold) is refused."""
        with self._cond:
            self._wait(lambda: self._program is not None, job_failed)
            fu = self._unreachable
            if fu is not None and fmt != "csv":
                raise UnreachableError(f"program is not runnable: first unreachable target at G-code line "
                                       f"{fu.gcode_line} ({fu.why()})", **fu.error_details())
            cold = self._cold
            if cold is not None and fmt != "csv":
                raise ColdExtrusionError(f"program is not runnable: {cold.message}", **{
                    k: v for k, v in s.to_plain(cold).items() if k != "message"})
            assert self._program is not None            # the wait ended ready
            return self._program

    def t_end_s(self, job_failed: Callable[[], FabricError | None]) -> np.ndarray | TimesSoFar | None:
        """The time at each row (None for a program that is not runnable): all of them once the cycle time is
        known, or while it is computed a :class:`TimesSoFar` whose rows wait for their times (a CSV export
        follows the computation block by block)."""
        with self._cond:
            self._wait(lambda: self._timed or self._timed_rows >= 0, job_failed)
            if self._timed:
                return self._t_end_s
            assert self._t_end_s is not None
            return TimesSoFar(self, self._t_end_s, job_failed)

    def wait_timed(self, rows: int, job_failed: Callable[[], FabricError | None]) -> None:
        """Wait until the first ``rows`` rows' times are known (or the job failed: its error)."""
        with self._cond:
            self._wait(lambda: self._timed or self._timed_rows >= rows, job_failed)


class TimesSoFar:
    """The rows' times while they are computed: indexing waits until the rows asked for are timed."""

    def __init__(self, handoff: PlanHandoff, t_end_s: np.ndarray, job_failed: Callable[[], FabricError | None]
                 ) -> None:
        self._handoff, self._t_end_s, self._job_failed = handoff, t_end_s, job_failed

    def __len__(self) -> int:
        return len(self._t_end_s)

    def __getitem__(self, rows: np.ndarray) -> np.ndarray:
        rows = np.asarray(rows)
        if rows.size:
            self._handoff.wait_timed(int(rows.max()) + 1, self._job_failed)
        return self._t_end_s[rows]
