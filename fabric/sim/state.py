"""The twin's whole mutable state as one object: what must be saved to bring a print back exactly.

Everything the twin changes while it runs lives here (its collaborators hold
only configuration and caches), so a snapshot is :meth:`TwinState.to_dict` and
a restore is :meth:`TwinState.from_dict`: plain values and numpy arrays that
the fabric's msgpack codec carries as they are. The loaded program is not
copied into the snapshot (it can be a million rows, and it is already a
content-addressed artifact): the snapshot names its row count and the caller
hands the same program back on restore. Timelines are not saved either: each
leg keeps the spec that rebuilds its timeline exactly (:mod:`fabric.sim.legs`).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fabric.motion.program import Program
from fabric.motion.thermal import Thermal
from fabric.schemas.states import Station
from fabric.sim.deposition import Deposition
from fabric.sim.legs import Leg, PoseSpec, thermal_from_dict, thermal_to_dict
from fabric.sim.types import Event
from fabric.wire.errors import ValidationError

__all__ = ["JobState", "ResumePoint", "TwinState", "SNAPSHOT_VERSION"]

SNAPSHOT_VERSION = 1


@dataclass
class ResumePoint:
    """Where a paused or stopped print left the path: ``s_mm`` along program ``row``, at ``pose``."""

    row: int
    s_mm: float
    pose: PoseSpec

    def to_dict(self) -> dict[str, Any]:
        return {"row": self.row, "s_mm": self.s_mm, "pose": self.pose.to_dict()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ResumePoint:
        return cls(int(d["row"]), float(d["s_mm"]), PoseSpec.from_dict(d["pose"]))


@dataclass
class JobState:
    """Progress of the running job, reset when it starts.

    ``extruded_mm3``: volume of the rows completed so far (plus pieces of rows
    cut short); ``carry_mm3``: per program row, the volume of a row cut short
    and not yet recorded as a bead (it is added to the bead when the row
    completes, or recorded as a partial bead if the job ends first).
    """

    extruded_mm3: float = 0.0
    retract_total_mm: float = 0.0
    retracted: bool = False
    carry_mm3: dict[int, float] = field(default_factory=dict)
    extruder_on: bool = False
    layer: int = -1
    row: int = 0
    resume_at: ResumePoint | None = None
    pause_retract_mm: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"extruded_mm3": self.extruded_mm3, "retract_total_mm": self.retract_total_mm,
                "retracted": self.retracted, "carry_mm3": [[r, v] for r, v in sorted(self.carry_mm3.items())],
                "extruder_on": self.extruder_on, "layer": self.layer, "row": self.row,
                "resume_at": self.resume_at.to_dict() if self.resume_at else None,
                "pause_retract_mm": self.pause_retract_mm}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> JobState:
        return cls(float(d["extruded_mm3"]), float(d["retract_total_mm"]), bool(d["retracted"]),
                   {int(r): float(v) for r, v in d["carry_mm3"]}, bool(d["extruder_on"]), int(d["layer"]),
                   int(d["row"]), ResumePoint.from_dict(d["resume_at"]) if d["resume_at"] else None,
                   float(d["pause_retract_mm"]))


@dataclass
class TwinState:
    """Lifecycle, clock, work object, heaters, overrides, program, rest pose, event count, beads, legs, job
    and the events of commands not yet reported."""

    work_T: np.ndarray
    rest_q_rad: np.ndarray
    rest_T: np.ndarray
    rng: np.random.Generator
    state: Station = Station.IDLE
    reason: str = ""
    t_sim_s: float = 0.0
    thermal: Thermal = field(default_factory=Thermal)
    speed_r: float = 1.0
    flow_r: float = 1.0
    program: Program | None = None
    estimate_s: float = 0.0
    t_started_s: float | None = None
    t_ended_s: float | None = None
    seq: int = 0
    beads: Deposition = field(default_factory=Deposition)
    legs: list[Leg] = field(default_factory=list)
    job: JobState = field(default_factory=JobState)
    pending: list[Event] = field(default_factory=list)     # events of commands, reported by the next advance

    def to_dict(self, with_beads: bool = True) -> dict[str, Any]:
        """The state as plain values and arrays (the program by its row count; see module docstring).
        ``with_beads`` False leaves the bead arrays out (a checkpoint stores them incrementally) and
        keeps their count."""
        return {
            "version": SNAPSHOT_VERSION,
            "state": str(self.state), "reason": self.reason, "t_sim_s": self.t_sim_s,
            "work_T": self.work_T.copy(), "rest_q_rad": self.rest_q_rad.copy(), "rest_T": self.rest_T.copy(),
            "rng": json.dumps(self.rng.bit_generator.state),   # 128-bit integers: as JSON text
            "thermal": thermal_to_dict(self.thermal), "speed_r": self.speed_r, "flow_r": self.flow_r,
            "program_rows": len(self.program) if self.program is not None else None,
            "estimate_s": self.estimate_s, "t_started_s": self.t_started_s, "t_ended_s": self.t_ended_s,
            "seq": self.seq, "beads": self.beads.to_arrays() if with_beads else None,
            "bead_count": len(self.beads),
            "legs": [leg.to_dict() for leg in self.legs], "job": self.job.to_dict(),
            "pending": [_event_to_dict(e) for e in self.pending],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], program: Program | None,
                  beads: dict[str, np.ndarray] | None = None) -> TwinState:
        """The state saved by :meth:`to_dict`, with ``program`` the one it was running (and ``beads``,
        when they were saved apart). Leg timelines are left unbuilt: the twin rebuilds them."""
        if d.get("version") != SNAPSHOT_VERSION:
            raise ValidationError(f"twin snapshot version {d.get('version')!r}, expected {SNAPSHOT_VERSION}",
                                  field="version")
        rows = d["program_rows"]
        if (rows is None) != (program is None) or (program is not None and len(program) != rows):
            have = len(program) if program is not None else None
            raise ValidationError(f"the snapshot ran a program of {rows} rows, got one of {have}", field="program")
        bead_arrays = d["beads"] if d["beads"] is not None else beads
        if not bead_arrays and d["bead_count"] == 0:
            bead_arrays = Deposition().to_arrays()
        if bead_arrays is None or len(bead_arrays["row"]) != d["bead_count"]:
            have = None if bead_arrays is None else len(bead_arrays["row"])
            raise ValidationError(f"the snapshot recorded {d['bead_count']} beads, got {have}", field="beads")
        rng = np.random.default_rng()
        rng.bit_generator.state = json.loads(d["rng"])
        return cls(
            work_T=np.asarray(d["work_T"], float), rest_q_rad=np.asarray(d["rest_q_rad"], float),
            rest_T=np.asarray(d["rest_T"], float), rng=rng, state=Station(str(d["state"])), reason=str(d["reason"]),
            t_sim_s=float(d["t_sim_s"]), thermal=thermal_from_dict(d["thermal"]), speed_r=float(d["speed_r"]),
            flow_r=float(d["flow_r"]), program=program, estimate_s=float(d["estimate_s"]),
            t_started_s=_opt_float(d["t_started_s"]), t_ended_s=_opt_float(d["t_ended_s"]), seq=int(d["seq"]),
            beads=Deposition.from_arrays(program, bead_arrays), legs=[Leg.from_dict(x) for x in d["legs"]],
            job=JobState.from_dict(d["job"]), pending=[_event_from_dict(e) for e in d["pending"]],
        )


def _event_to_dict(e: Event) -> dict[str, Any]:
    return {"seq": e.seq, "t_sim_s": e.t_sim_s, "kind": e.kind, "row": e.row, "gcode_line": e.gcode_line,
            "layer": e.layer, "data": dict(e.data)}


def _event_from_dict(d: dict[str, Any]) -> Event:
    return Event(int(d["seq"]), float(d["t_sim_s"]), str(d["kind"]), int(d["row"]), int(d["gcode_line"]),
                 int(d["layer"]), dict(d["data"]))


def _opt_float(v: Any) -> float | None:
    return None if v is None else float(v)
