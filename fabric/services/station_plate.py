"""The part on the plate: when a print puts one there, what it allows and refuses, and taking it off.

The station owns it (its fields live in :class:`~fabric.store.journal.StationMeta`,
so it survives restarts). Every method runs on the station's writer, like any
other change of the twin.
"""
from __future__ import annotations

from fabric.sim.twin import Twin
from fabric.store.journal import StationMeta
from fabric.wire.errors import StateError, ValidationError

__all__ = ["PlateGuard"]


class PlateGuard:
    """The part on the plate of one station (``twin`` and ``meta`` are the station's, for its whole life)."""

    def __init__(self, twin: Twin, meta: StationMeta) -> None:
        self.twin, self.meta = twin, meta

    def track(self, extruded_mm3: float) -> None:
        """The first bead of a print puts a part on the plate (the print's ``started`` event says so to
        followers); it stays there, with what was deposited on it, until the operator says it is off
        (:meth:`clear`, event ``plate_cleared``), whatever happens to the job or the station."""
        meta = self.meta
        if not meta.plate_occupied and len(self.twin.beads):
            meta.plate_occupied, meta.plate_job_id, meta.plate_program_id = True, meta.job_id, meta.program_id
        if meta.plate_occupied and meta.plate_program_id == meta.program_id:
            meta.plate_mm3 = max(meta.plate_mm3, float(extruded_mm3))

    def text(self) -> str:
        """What is on the plate, in words."""
        m = self.meta
        return f"the part of job {m.plate_job_id or '(loaded by hand)'} ({m.plate_mm3:.0f} mm3)"

    def refuse_load(self) -> None:
        """A program is loaded onto a clear plate only."""
        if self.meta.plate_occupied:
            raise StateError(f"cannot load a program while the plate holds {self.text()}: take it off "
                             f"and say so first (fabric-cli plate-clear, or job next)", state=self.twin.state,
                             command="load", plate="occupied", plate_job_id=self.meta.plate_job_id)

    def refuse_start(self, command: str, from_layer: int | None) -> None:
        """A print from the start needs a clear plate and a job that has not printed yet (a job is printed
        once: its record is its history); a restart at a layer needs this program's part on the plate."""
        m, state = self.meta, self.twin.state
        if from_layer is None and m.job_id and self.twin.s.t_ended_s is not None:
            raise StateError(f"cannot {command} job {m.job_id} from the beginning: its print ended "
                             f"({self.twin.reason}); print it again as a new job (fabric-cli job submit), or go "
                             f"on at a layer of its part ({self._layer_hint()})", state=state, command=command,
                             job_id=m.job_id)
        if from_layer is None and m.plate_occupied:
            raise StateError(f"cannot {command} from the beginning: the plate holds {self.text()}; take it off "
                             f"and say so (fabric-cli plate-clear, or job next), or go on at a layer of it "
                             f"({self._layer_hint()})", state=state, command=command, plate="occupied",
                             plate_job_id=m.plate_job_id)
        if from_layer is not None and not m.plate_occupied:
            raise StateError(f"cannot {command} at layer {from_layer + 1}: the plate is clear, there is no part to "
                             f"go on with; start from the beginning", state=state, command=command, plate="clear")
        if from_layer is not None and m.plate_program_id != m.program_id:
            raise StateError(f"cannot {command} at layer {from_layer + 1}: the plate holds {self.text()}, not "
                             f"this program's part", state=state, command=command, plate="occupied",
                             plate_job_id=m.plate_job_id)
        if from_layer is not None:
            self.refuse_in_the_air(command, from_layer)

    def _layer_hint(self) -> str:
        """Which ``start --layer`` goes on with the part on the plate: its top layer (where it ends)."""
        top = self.top_layer()
        if top < 0 or self.meta.plate_program_id != self.meta.program_id:
            return "start --layer N"
        return f"start --layer {top + 1}: it goes on where the part ends, in layer {top + 1}"

    def going_on(self) -> str:
        """What a restart on the part on the plate may do, in words: go on where it ends (at its top layer: a
        layer under it would be printed into the part), or nothing is left to print."""
        top = self.top_layer()
        if top < 0:
            return "start from the beginning: the plate holds none of it"
        try:
            self.twin.restart_point(top)
        except ValidationError:
            return (f"the part is printed to its last layer ({top + 1}): take it off and say so (fabric-cli "
                    f"plate-clear) to print it again")
        return f"go on where the part ends: start --layer {top + 1}"

    def top_layer(self) -> int:
        """The highest layer (0-based) with a bead of the part on the plate; -1 when there is none."""
        beads = self.twin.beads
        return int(beads.layer.max()) if len(beads) else -1

    def refuse_in_the_air(self, command: str, from_layer: int) -> None:
        """Going on at a layer above the part's top and the one after it would lay beads on nothing: the part
        is printed up to its top layer (partly, where a print was cut short), so it goes on at that layer or
        the next, not higher (a typo of ``--layer 30`` for ``--layer 13`` printed layer 30 in the air).
        Layers under the top are the collision check's to refuse (the nozzle would go through the part)."""
        if self.twin.program is None:                      # nothing loaded: the start refuses that itself
            return
        self.twin.moves.layer_start_row(from_layer)       # a layer the program has not: that error first
        top = self.top_layer()
        if top < 0 or from_layer <= top + 1:
            return
        raise StateError(f"cannot {command} at layer {from_layer + 1}: the part on the plate is printed up to "
                         f"layer {top + 1}, so layer {from_layer + 1} would be laid {from_layer - top - 1} "
                         f"layer(s) above it, in the air; go on at layer {top + 1} (where it ends) or {top + 2}",
                         state=self.twin.state, command=command, from_layer=from_layer + 1, top_layer=top + 1)

    def refuse_probing(self) -> None:
        """Calibrating probes the plate's top face at points spread over it: with a part on the plate the probe
        would touch it (no probe point is certified against the part), so it is refused until the part is off."""
        if self.meta.plate_occupied:
            raise StateError(f"cannot calibrate while the plate holds {self.text()}: the probe touches the plate "
                             f"where the part may stand; take it off and say so (fabric-cli plate-clear) first",
                             state=self.twin.state, command="calibrate", plate="occupied",
                             plate_job_id=self.meta.plate_job_id)

    def clear(self) -> str:
        """The operator took the part off (refused while it is being printed); what was taken off, in words
        ("" when the plate was clear already)."""
        if self.twin.state.print_on:
            raise StateError(f"the part is still being printed ({self.twin.state}): stop first",
                             state=self.twin.state, command="clear_plate")
        m = self.meta
        if not m.plate_occupied:
            # no part on record (a print stopped before its first bead), but the operator's word is noted all
            # the same: a queue waiting for the plate goes on from it (it did not: plate-clear said "clear
            # already" and the next job kept waiting for "job next")
            self.twin.note("plate_cleared", {"job_id": "", "plate_mm3": 0.0})
            return ""
        what = self.text()
        self.twin.note("plate_cleared", {"job_id": m.plate_job_id, "plate_mm3": round(m.plate_mm3, 3)})
        m.plate_occupied, m.plate_job_id, m.plate_program_id, m.plate_mm3 = False, "", "", 0.0
        self.twin.clear_plate()
        return what
