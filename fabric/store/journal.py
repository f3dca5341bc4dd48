"""The station's journal: what it writes as it runs, and how a restarted station comes back exactly.

The station records each tick's events and its clock mark, and checkpoints
the twin at a bounded cadence and after every command (see
:mod:`fabric.store.station`). :meth:`StationJournal.restore` rebuilds the twin
from the last checkpoint, advances it to the clock mark (the twin is
deterministic: it re-deposits exactly what had been deposited, and the events
it re-emits are already in the log) and then stops it dead there as
``interrupted``: the robot is where the station lost it, not at home, and the
ready checklist says it must be recovered.
"""
from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass
from typing import Any

from fabric import schemas as s
from fabric.programs import program_from_artifact
from fabric.sim.twin import Twin
from fabric.store.artifacts import ArtifactStore
from fabric.store.station import StationStore

__all__ = ["Restored", "StationJournal", "StationMeta", "DEFAULT_CHECKPOINT_PERIOD_S"]

log = logging.getLogger("fabric.store.journal")
DEFAULT_CHECKPOINT_PERIOD_S = 1.0
REST_MARK_S = 1.0                   # at rest, an eventless tick moves the clock mark at most this often (wall s)
LOADED_PIN = "station:loaded"


@dataclass
class StationMeta:
    """What the station keeps beside the twin: the loaded program and job, and the real-time factor."""

    program_id: str = ""
    job_id: str = ""
    rtf: float = 1.0
    layers_total: int = 0
    planned_mm3: float = 0.0          # what the loaded program deposits in all
    # the part on the plate: from the first bead of a print until the operator says the plate is clear
    plate_occupied: bool = False
    plate_job_id: str = ""
    plate_program_id: str = ""
    plate_mm3: float = 0.0


@dataclass
class Restored:
    """A twin brought back from the journal, the station's meta, and the events to publish now
    (those the replay produced beyond the log, then the interruption's)."""

    twin: Twin
    meta: StationMeta
    events: list[Any]


class StationJournal:
    """Writes the station's durable state and restores it (see the module docstring)."""

    def __init__(self, store: StationStore, artifacts: ArtifactStore,
                 period_s: float = DEFAULT_CHECKPOINT_PERIOD_S) -> None:
        self.store = store
        self.artifacts = artifacts
        self.period_s = float(period_s)
        self._last_s = float("-inf")
        self._mark_s = float("-inf")                          # when the clock mark was last written (monotonic)
        self.checkpoints = 0
        self._cell: tuple[Any, str] | None = None          # the twin's cell and its fingerprint, found once

    # Writing -------------------------------------------------------------------------------

    def record_tick(self, events: list[s.Event], t_sim_s: float, at_rest: bool = False) -> None:
        """This tick's events and the clock mark (before they are published).

        ``at_rest``: nothing moves and no print runs, so a restore replays nothing from the mark but the clock
        and the heaters; a tick without events then moves the mark at most every ``REST_MARK_S`` (an idle
        station wrote its database 50 times a second). A tick with events always writes them and the mark."""
        now = time.monotonic()
        if at_rest and not events and now - self._mark_s < REST_MARK_S:
            return
        self.store.record_tick(events, t_sim_s)
        self._mark_s = now

    def keep_program(self, artifact: s.Artifact) -> None:
        """Keep the loaded program's artifact here (pinned), so a restart needs no other service."""
        self.artifacts.put(artifact)
        self.artifacts.unpin(LOADED_PIN)
        self.artifacts.pin(artifact.artifact_id, LOADED_PIN)

    def checkpoint(self, twin: Twin, meta: StationMeta, *, force: bool = False) -> bool:
        """Save the twin and ``meta`` if the period has passed (or ``force``); True when saved."""
        now = time.monotonic()
        if not force and now - self._last_s < self.period_s:
            return False
        state = {"meta": asdict(meta), "twin": twin.snapshot(with_beads=False), "cell": self._fingerprint(twin.cell),
                 "cell_name": twin.cell.name}
        epoch = f"{meta.program_id}:{twin.s.t_started_s}"
        self.store.save_checkpoint(state, epoch, twin.beads)
        self._last_s = now
        self.checkpoints += 1
        return True

    def _fingerprint(self, cell: Any) -> str:
        if self._cell is None or self._cell[0] is not cell:
            self._cell = (cell, cell.fingerprint())
        return self._cell[1]

    # Restoring ------------------------------------------------------------------------------

    def restore(self, cell: Any) -> Restored | None:
        """The twin as the last run left it (None when nothing was ever saved). Raises a FabricError
        when the checkpoint cannot be used (e.g. its program artifact is gone)."""
        ck = self.store.load()
        if ck is None:
            return None
        meta = StationMeta(**ck.state["meta"])
        saved = ck.state.get("cell")                          # older checkpoints do not say: taken as this cell
        if saved is not None and saved != self._fingerprint(cell):
            return self._other_cell(cell, meta, str(ck.state.get("cell_name", "?")))
        program = program_from_artifact(self.artifacts.get(meta.program_id)) if meta.program_id else None
        twin = Twin.from_snapshot(cell, ck.state["twin"], program, ck.beads)
        last_seq = self.store.last_seq()
        replayed = twin.advance(max(ck.t_mark_s - twin.t_sim_s, 0.0))
        fresh = [e for e in replayed if e.seq > last_seq]
        if fresh:
            log.warning("the replay to the clock mark produced %d events beyond the log", len(fresh))
        twin.interrupt("the station restarted: the robot stopped where the station lost it; recover to go on")
        events = fresh + twin.advance(0.0)
        log.info("restored the twin at t_sim %.3f s (%s, %d beads) from the checkpoint and the clock mark",
                 twin.t_sim_s, twin.state, len(twin.beads))
        return Restored(twin, meta, events)

    def _other_cell(self, cell: Any, meta: StationMeta, saved_name: str) -> Restored:
        """The last checkpoint is of another cell (the station was started with another cell file): its pose,
        program and beads mean nothing here. A fresh twin at this cell's home; a part said to be on the plate
        is still said to be there (the operator says when it is off)."""
        log.warning("the last checkpoint is of another cell (%r, not %r as configured now): not restored; the "
                    "twin starts at this cell's home%s", saved_name, cell.name,
                    ", the plate still marked occupied" if meta.plate_occupied else "")
        twin = Twin(cell)
        twin.number_events_after(self.store.last_seq())
        kept = StationMeta(rtf=meta.rtf, plate_occupied=meta.plate_occupied, plate_job_id=meta.plate_job_id,
                           plate_program_id=meta.plate_program_id, plate_mm3=meta.plate_mm3)
        return Restored(twin, kept, [])

    def last_seq(self) -> int:
        """The last event's sequence number in the log (a fresh twin's events go on from there)."""
        return self.store.last_seq()
