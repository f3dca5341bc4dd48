"""Runs the twin's motion legs in simulated time: row events, heaters, retractions and beads.

Walking a leg to a local time processes, in order, the rows that start or
complete by then: a row's start may change the layer (an event), turn the
extruder on or off (state only: it is published on the extrusion stream, not
as one event per bead) and change a heater set point; its end reports a
temperature reached or counts a retraction. Rows of the program that complete are deposited as beads, from the
row's own start and end points with the flow per mm times the distance the row
covered; a row cut short (pause, stop, override, fault) keeps its volume so far
in ``carry_mm3`` and adds it to the bead when the row completes on resume, so a
paused print deposits the same beads as an uninterrupted one. When a job ends
with a row cut short, that row is recorded as a partial bead.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from fabric.motion.cold import DEFAULT_MIN_EXTRUDE_C, min_extrude_c
from fabric.motion.program import MOVEL, NOZZLE, RETRACT, SET_TEMP, WAIT_TEMP, Program
from fabric.motion.thermal import HEATER_NAMES
from fabric.robot.frames import R_from_quat, inv_T, make_T
from fabric.schemas.states import Station
from fabric.sim.builder import LegBuilder
from fabric.sim.deposition import nozzle_axes
from fabric.sim.legs import Leg
from fabric.sim.material import DepositGuard
from fabric.sim.state import TwinState
from fabric.sim.types import Event

__all__ = ["DEFAULT_MIN_EXTRUDE_C", "Interlock", "DepositTrip", "LegRunner"]

PARTIAL_MIN_MM3 = 1e-9       # a partial bead of less is none (a row cut where it began)


@dataclass
class Interlock:
    """A cold-extrusion interlock: row ``row`` would start extruding at ``t_s`` with the nozzle at
    ``nozzle_c``, below the material's minimum ``min_c``; local row ``j`` of the running leg."""

    t_s: float
    row: int
    j: int
    nozzle_c: float
    min_c: float

    @property
    def reason(self) -> str:
        return (f"cold extrusion prevented: the nozzle is at {self.nozzle_c:.0f} C, below the material's "
                f"minimum extrusion temperature {self.min_c:.0f} C")


@dataclass(frozen=True)
class DepositTrip:
    """The twin's last guard: row ``row`` (local row ``j`` of the running leg) would lay its bead into the part
    on the plate (its layer ``existing_layer``, ``length_mm`` inside) at ``t_s``; G-code line ``gcode_line``,
    layer ``layer``."""

    t_s: float
    row: int
    j: int
    gcode_line: int
    layer: int
    existing_layer: int
    length_mm: float

    @property
    def reason(self) -> str:
        return (f"deposit guard: G-code line {self.gcode_line} (layer {self.layer + 1}) would lay its bead into the "
                f"part on the plate, along its layer {self.existing_layer + 1} for {self.length_mm:.1f} mm: the "
                f"print stops before it")


class LegRunner:
    """Owns no state: walks the legs of ``state`` and records what happens in it. A program row that
    would start extruding with the nozzle below the material's minimum temperature is not started:
    the walk stops before it and ``tripped`` says why (the twin pauses the print there). Nor is a row
    whose bead would go into the material on the plate when the run began (``guard``, set by the twin
    for a run on a part: a restart, a recovery): ``tripped`` says so (the twin faults there)."""

    def __init__(self, state: TwinState, builder: LegBuilder) -> None:
        self.state = state
        self.builder = builder
        self.tripped: Interlock | DepositTrip | None = None
        self.guard: DepositGuard | None = None
        self._min_c: tuple[int, float | None] | None = None
        self._layer_z: tuple[int, dict[int, float]] | None = None

    # Queue ---------------------------------------------------------------------------

    def enqueue(self, leg: Leg) -> None:
        """Append ``leg``; it starts now if the robot is idle."""
        self.state.legs.append(leg)
        if len(self.state.legs) == 1:
            self.place(leg, self.state.t_sim_s)

    def place(self, leg: Leg, t0: float) -> None:
        """Start ``leg`` at ``t0``, timing it now if it was not timed yet."""
        leg.place(t0, leg.tl if leg.tl is not None else self.builder.build(leg.spec, t0))

    # Walking a leg ---------------------------------------------------------------------

    def run_leg(self, leg: Leg, tau: float, final: bool, events: list[Event]) -> None:
        """Process the rows of ``leg`` that start or complete by local time ``tau``."""
        ns, nd = leg.cursor(tau, final)
        if ns == leg.started and nd == leg.done:
            return
        if leg.main and self.guard is not None and ns > leg.started:
            ns, nd = self._guarded(leg, ns, nd)
        job = self.state.job
        it = leg.interesting
        for j in it[np.searchsorted(it, leg.done):np.searchsorted(it, ns)].tolist():
            if j >= leg.started:
                if leg.main and leg.ext[j] == 1 and not job.extruder_on and self._too_cold(leg, j):
                    ns, nd = j, min(nd, j)               # row j is not started: the twin pauses here
                    break
                self._row_start(leg, j, events)
            if j < nd:
                self._row_done(leg, j, events)
        if leg.main:
            if nd > leg.done:
                self._deposit(leg, leg.done, nd)
                job.extruded_mm3 += float(leg.cumvol_mm3[nd] - leg.cumvol_mm3[leg.done])
            if ns > 0:
                job.row = leg.timeline.start_row + ns - 1
        leg.started, leg.done = ns, nd

    def _guarded(self, leg: Leg, ns: int, nd: int) -> tuple[int, int]:
        """Rows ``leg.started .. ns-1`` would start now: stop before the first whose bead goes into the part on
        the plate, and trip (the twin faults there)."""
        assert self.guard is not None
        tl = leg.timeline
        k = self.guard.first_in(tl.start_row + leg.started, tl.start_row + ns)
        if k is None:
            return ns, nd
        r = int(self.guard.rows[k])
        j = r - tl.start_row
        p = tl.program
        self.tripped = DepositTrip(leg.t0 + float(tl.t_start_s[j]), r, j, int(p.gcode_line[r]), int(p.layer[r]),
                                   int(self.guard.existing_layer[k]), float(self.guard.length_mm[k]))
        return j, min(nd, j)

    def min_extrude_c(self) -> float | None:
        """The loaded material's minimum extrusion temperature: the program's ``min_extrude_temp_c``;
        else 170 C (as printer firmware) when the program heats the nozzle; else none (a material
        extruded cold: clay, concrete)."""
        p = self.state.program
        if p is None:
            return None
        if self._min_c is None or self._min_c[0] != id(p):
            self._min_c = (id(p), min_extrude_c(p))      # the planner's check uses the same rule
        return self._min_c[1]

    def layer_z_mm(self, layer: int, fallback_mm: float) -> float:
        """The Z a layer is printed at: that of its first extruding move (its first row is often the travel
        from the layer below, or the approach from above); ``fallback_mm`` for a layer that extrudes nothing."""
        p = self.state.program
        if p is None:
            return fallback_mm
        if self._layer_z is None or self._layer_z[0] != id(p):
            rows = np.flatnonzero((p.op == MOVEL) & (p.flow_mm3_mm > 0) & (p.layer >= 0))
            layers, first = np.unique(p.layer[rows], return_index=True)
            self._layer_z = (id(p), dict(zip(layers.tolist(), p.xyz_mm[rows[first], 2].tolist(), strict=True)))
        return float(self._layer_z[1].get(layer, fallback_mm))

    def _too_cold(self, leg: Leg, j: int) -> bool:
        min_c = self.min_extrude_c()
        if min_c is None:
            return False
        t = leg.t0 + float(leg.timeline.t_start_s[j])
        nozzle_c = self.state.thermal.temp_at(NOZZLE, t)
        if nozzle_c >= min_c:
            return False
        self.tripped = Interlock(t, leg.timeline.start_row + j, j, nozzle_c, min_c)
        return True

    def _row_start(self, leg: Leg, j: int, events: list[Event]) -> None:
        tl, job = leg.timeline, self.state.job
        p, r, t = tl.program, tl.start_row + j, leg.t0 + float(tl.t_start_s[j])
        if leg.main:
            job.row = r
        if leg.main and p.layer[r] >= 0 and p.layer[r] != job.layer:
            job.layer = int(p.layer[r])
            self.emit(events, t, "layer", {"z_mm": self.layer_z_mm(job.layer, float(p.xyz_mm[r, 2]))})
        if leg.ext[j] >= 0:             # the extruder's state travels on the extrusion stream, not as events
            job.extruder_on = bool(leg.ext[j])
        if p.op[r] == SET_TEMP:
            self.state.thermal.set_target(int(p.aux[r]), float(p.value[r]), t)

    def _row_done(self, leg: Leg, j: int, events: list[Event]) -> None:
        tl, job, thermal = leg.timeline, self.state.job, self.state.thermal
        p, r, t = tl.program, tl.start_row + j, leg.t0 + float(tl.t_end_s[j])
        if p.op[r] == WAIT_TEMP:
            h = int(p.aux[r])
            self.emit(events, t, "temp_reached", {"heater": HEATER_NAMES[h], "temp_c": thermal.temp_at(h, t),
                                                  "target_c": thermal.target(h)})
        elif p.op[r] == RETRACT:
            job.retract_total_mm += float(p.value[r])
            job.retracted = bool(p.value[r] < 0)

    def _deposit(self, leg: Leg, a: int, b: int) -> None:
        """Record the beads of main-program rows ``a .. b-1`` of ``leg`` (just completed), vectorised."""
        tl = leg.timeline
        p = tl.program
        j = np.arange(a, b)
        r = tl.start_row + j
        keep = (p.op[r] == MOVEL) & (p.flow_mm3_mm[r] > 0)
        j, r = j[keep], r[keep]
        if len(j) == 0:
            return
        keep = tl.row_length_mm(j) > 0
        j, r = j[keep], r[keep]
        if len(j) == 0:
            return
        vol = leg.vol_mm3[j].copy()
        if j[0] == 0:
            vol[0] += self.state.job.carry_mm3.pop(int(r[0]), 0.0)
        _, start, _ = tl.from_pose(j)
        self.state.beads.add(r, p.layer[r], start, p.xyz_mm[r], vol, p.flow_mm3_mm[r], _bead_axes(p, r))

    # Ending a leg ----------------------------------------------------------------------

    def finish_leg(self, leg: Leg, events: list[Event]) -> None:
        """The head leg ended: keep the unfinished row's volume, record the pose, fire its end events."""
        st = self.state
        tl = leg.timeline
        p = tl.program
        if leg.partial_end and leg.main:
            j = leg.n_rows - 1
            r = tl.start_row + j
            if p.op[r] == MOVEL:
                s, _ = tl.profile(np.array([j]), np.array([leg.t_cut - tl.t_start_s[j]]))
                piece = float(p.flow_mm3_mm[r]) * tl.flow_r * float(s[0])
                st.job.carry_mm3[r] = st.job.carry_mm3.get(r, 0.0) + piece
                st.job.extruded_mm3 += piece
        smp = tl.sample(leg.t_cut)
        st.rest_q_rad = np.array(smp.q_rad, dtype=float)
        st.rest_T = p.wobj @ make_T(R_from_quat(smp.quat_wxyz), smp.xyz_mm)
        st.legs.pop(0)
        t_end = leg.t0 + leg.t_cut
        for kind in leg.end_kinds:
            self.on_end(kind, t_end, events)
        if st.legs:
            self.place(st.legs[0], t_end)

    def on_end(self, kind: str, t: float, events: list[Event]) -> None:
        """Fire the end event ``kind`` of a leg (finished, stopped, paused, resumed, home) at ``t``."""
        st = self.state
        job = st.job
        if kind == "finished":
            st.state, st.reason = Station.IDLE, "finished"
            st.t_ended_s = t
            self.emit(events, t, kind, self.totals(t))
        elif kind == "stopped":
            self.record_partial()
            st.t_ended_s = t
            self.emit(events, t, kind, self.totals(t))
        elif kind in ("resumed", "recovered", "at_layer"):
            job.resume_at = None
            if st.state.printing and kind != "at_layer":     # the move back is over: say so, not "-ing"
                st.reason = kind
            self.emit(events, t, kind)
        elif kind == "home":
            if not st.state.in_print:
                st.reason = "at home"
            self.emit(events, t, kind)
        elif kind == "jogged":
            st.reason = kind
            xyz = (inv_T(st.work_T) @ st.rest_T)[:3, 3]
            self.emit(events, t, kind, {"xyz_mm": [round(float(v), 6) for v in xyz]})
        elif kind.startswith("extruded"):
            length_mm = float(kind.partition(":")[2] or 0.0)
            st.reason = f"{'extruded' if length_mm > 0 else 'retracted'} {abs(length_mm):g} mm"
            self.emit(events, t, "extruded", {"filament_mm": length_mm})
        elif kind == "paused":          # why: the operator, or the cold-extrusion interlock (its reason)
            at = job.resume_at
            where = {} if at is None else {"resume_row": at.row, "resume_s_mm": at.s_mm,
                                           "xyz_mm": at.pose.xyz_mm.tolist()}
            self.emit(events, t, kind, {**where, "reason": st.reason})
        else:
            self.emit(events, t, kind)

    def totals(self, t: float) -> dict[str, Any]:
        """What a finished or stopped job did: simulated duration, volume, filament, beads."""
        st = self.state
        job = st.job
        filament_mm = job.extruded_mm3 / self.builder.config.filament_area_for_mm2(st.program) + job.retract_total_mm
        return {"elapsed_s": t - (st.t_started_s or 0.0), "extruded_mm3": job.extruded_mm3,
                "filament_mm": filament_mm, "beads": len(st.beads)}

    def emit(self, events: list[Event], t: float, kind: str, data: dict[str, Any] | None = None) -> None:
        """Append the next event (``seq`` counts on across the twin's life)."""
        st = self.state
        p = st.program
        row = st.job.row
        g = int(p.gcode_line[min(row, len(p) - 1)]) if p is not None else -1
        st.seq += 1
        events.append(Event(st.seq, float(t), kind, row, g, st.job.layer, data or {}))

    def record_partial(self) -> None:
        """The row in progress when a job ends early: a partial bead from its start to the stop point."""
        st = self.state
        job, p = st.job, st.program
        if p is None or not job.carry_mm3:
            job.carry_mm3.clear()
            return
        for r, vol in sorted(job.carry_mm3.items()):
            if job.resume_at is not None and job.resume_at.row == r:
                end = job.resume_at.pose.xyz_mm
            else:
                end = (inv_T(p.wobj) @ st.rest_T)[:3, 3]
            start = p.xyz_mm[r - 1] if r > 0 else end
            if vol > PARTIAL_MIN_MM3:                 # a cut at a row's very start lays nothing
                st.beads.add(np.array([r]), p.layer[r:r + 1], start[None], np.asarray(end)[None], np.array([vol]),
                             p.flow_mm3_mm[r:r + 1], _bead_axes(p, np.array([r])))
        job.carry_mm3.clear()
        job.resume_at = None


def _bead_axes(program: Program, rows: np.ndarray) -> np.ndarray | None:
    """The nozzle axes beads of ``rows`` are laid with (plate frame): the rows' own for a multi-axis program,
    None (straight up) for a planar one."""
    if not program.meta.get("multiaxis", False):
        return None
    return nozzle_axes(program.quat_wxyz[rows])
