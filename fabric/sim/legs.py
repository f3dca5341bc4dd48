"""Motion legs: a timeline placed at an absolute time, and the recipe (spec) that rebuilds it exactly.

The twin's motion is a queue of legs. Each leg knows *how its timeline is
made* (its spec), not only the timeline itself, so the queue can be saved as
plain data and rebuilt bit for bit: the motion model is deterministic, and a
timeline is a function of its spec alone.

- :class:`ProgramLegSpec`: the loaded program from ``row`` on, starting from
  a given pose (``s_mm`` along that row, at ``v_mm_s``) or from wherever the
  robot rests when the leg begins. It is timed when it begins, with the
  heaters and overrides of that moment; those inputs are then frozen into the
  spec (:class:`ProgramStart`), so a saved leg is rebuilt with the same ones.
- :class:`StopLegSpec`: the controlled stop of another leg's timeline at a
  local time (pause and stop slow down along the path).
- :class:`AuxLegSpec`: the twin's own short moves (retract and lift, the way
  back down, homing) as explicit rows from an explicit start pose.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fabric.motion.program import MOVEL, RETRACT, SET_TEMP, WAIT_TEMP
from fabric.motion.thermal import HeaterParams, HeaterState, Thermal
from fabric.motion.timeline import Timeline
from fabric.wire.errors import ValidationError

__all__ = ["AuxLegSpec", "Leg", "LegSpec", "PoseSpec", "ProgramLegSpec", "ProgramStart", "StopLegSpec",
           "spec_from_dict", "thermal_from_dict", "thermal_to_dict"]


@dataclass
class PoseSpec:
    """Joints and TCP (plate frame) of a start or resume point."""

    q_rad: np.ndarray
    xyz_mm: np.ndarray
    quat_wxyz: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        return {"q_rad": np.asarray(self.q_rad, float), "xyz_mm": np.asarray(self.xyz_mm, float),
                "quat_wxyz": np.asarray(self.quat_wxyz, float)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PoseSpec:
        return cls(np.asarray(d["q_rad"], float), np.asarray(d["xyz_mm"], float), np.asarray(d["quat_wxyz"], float))


@dataclass
class ProgramStart:
    """The inputs a program leg was timed with: start time, start pose, heaters, overrides."""

    t0_s: float
    pose: PoseSpec
    thermal: Thermal
    speed_r: float
    flow_r: float

    def to_dict(self) -> dict[str, Any]:
        return {"t0_s": self.t0_s, "pose": self.pose.to_dict(), "thermal": thermal_to_dict(self.thermal),
                "speed_r": self.speed_r, "flow_r": self.flow_r}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ProgramStart:
        return cls(float(d["t0_s"]), PoseSpec.from_dict(d["pose"]), thermal_from_dict(d["thermal"]),
                   float(d["speed_r"]), float(d["flow_r"]))


@dataclass
class ProgramLegSpec:
    """The loaded program from ``row`` (see module docstring); ``pose`` None: from the rest joints."""

    row: int
    pose: PoseSpec | None = None
    s_mm: float = 0.0
    v_mm_s: float = 0.0
    frozen: ProgramStart | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"kind": "program", "row": self.row, "pose": self.pose.to_dict() if self.pose else None,
                "s_mm": self.s_mm, "v_mm_s": self.v_mm_s,
                "frozen": self.frozen.to_dict() if self.frozen else None}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ProgramLegSpec:
        return cls(int(d["row"]), PoseSpec.from_dict(d["pose"]) if d["pose"] is not None else None,
                   float(d["s_mm"]), float(d["v_mm_s"]),
                   ProgramStart.from_dict(d["frozen"]) if d["frozen"] is not None else None)


@dataclass
class StopLegSpec:
    """A controlled stop of the timeline of ``parent`` from its local time ``tau_s``."""

    parent: LegSpec
    tau_s: float

    def to_dict(self) -> dict[str, Any]:
        return {"kind": "stop", "parent": self.parent.to_dict(), "tau_s": self.tau_s}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> StopLegSpec:
        return cls(spec_from_dict(d["parent"]), float(d["tau_s"]))


@dataclass
class AuxLegSpec:
    """The twin's own moves: program rows (column name -> value) from ``start`` in plate frame ``wobj``;
    ``thermal`` (the heaters at ``t0_s``) times heat-up waits among them."""

    rows: list[dict[str, Any]]
    start: PoseSpec
    wobj: np.ndarray
    thermal: Thermal | None = None
    t0_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        rows = [{k: (np.asarray(v) if isinstance(v, (np.ndarray, list, tuple)) else v) for k, v in r.items()}
                for r in self.rows]
        return {"kind": "aux", "rows": rows, "start": self.start.to_dict(), "wobj": np.asarray(self.wobj, float),
                "thermal": thermal_to_dict(self.thermal) if self.thermal is not None else None, "t0_s": self.t0_s}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> AuxLegSpec:
        thermal = thermal_from_dict(d["thermal"]) if d.get("thermal") is not None else None
        return cls([dict(r) for r in d["rows"]], PoseSpec.from_dict(d["start"]), np.asarray(d["wobj"], float),
                   thermal, float(d.get("t0_s", 0.0)))


LegSpec = ProgramLegSpec | StopLegSpec | AuxLegSpec
_SPECS: dict[str, type[ProgramLegSpec] | type[StopLegSpec] | type[AuxLegSpec]] = {
    "program": ProgramLegSpec, "stop": StopLegSpec, "aux": AuxLegSpec}


def spec_from_dict(d: dict[str, Any]) -> LegSpec:
    """A leg spec from its :meth:`to_dict` form."""
    kind = d.get("kind")
    if kind not in _SPECS:
        raise ValidationError(f"unknown leg kind {kind!r}", field="kind")
    return _SPECS[kind].from_dict(d)


def thermal_to_dict(th: Thermal) -> dict[str, Any]:
    """Heater parameters and anchored states as plain values."""
    return {"params": [[p.power_w, p.capacity_j_k, p.resistance_k_w, p.tol_c, p.ambient_c, p.max_c]
                       for p in th.params],
            "states": [[st.t_s, st.temp_c, st.target_c] for st in th.states]}


def thermal_from_dict(d: dict[str, Any]) -> Thermal:
    """The inverse of :func:`thermal_to_dict` (exact: the closed forms re-anchor nowhere). Parameters saved
    by the first-order model before (four values: tau, tol, ambient, max) become today's heaters."""
    params = tuple(HeaterParams(*(float(v) for v in p)) if len(p) == 6 else default
                   for p, default in zip(d["params"], Thermal().params, strict=True))
    states = [HeaterState(*(float(v) for v in st)) for st in d["states"]]
    return Thermal(params, states)     # type: ignore[arg-type]


@dataclass
class Leg:
    """A timeline placed at an absolute start ``t0``, possibly cut short, with row cursors.

    A leg whose timeline is not built yet (``tl`` None) is timed when it is
    placed. A cut leg owns only its first ``n_rows`` rows and ends at
    ``t_cut`` (local seconds); ``partial_end`` says the last owned row is left
    unfinished. ``started`` / ``done`` count rows whose start / end has been
    processed. ``main`` legs run the loaded program (they extrude and deposit);
    ``end_kinds`` are the events fired when the leg ends.
    """

    spec: LegSpec
    main: bool
    end_kinds: list[str]
    tl: Timeline | None = None
    t0: float = float("nan")
    t_cut: float = 0.0
    n_rows: int = 0
    partial_end: bool = False
    started: int = 0
    done: int = 0
    placed: bool = False
    preview_s: float | None = None       # cache: duration of a lazy leg if it started now
    ext: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int8))
    interesting: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    vol_mm3: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cumvol_mm3: np.ndarray = field(default_factory=lambda: np.zeros(1))

    @property
    def timeline(self) -> Timeline:
        """The built timeline: every leg that is placed, or restored and rebuilt, has one."""
        if self.tl is None:
            raise RuntimeError("the leg's timeline is not built yet")
        return self.tl

    def place(self, t0: float, tl: Timeline) -> None:
        """Start the leg at absolute time ``t0`` with its timeline ``tl``."""
        self.tl = tl
        self.t0, self.placed = float(t0), True
        if not self.t_cut and not self.n_rows:
            self.t_cut, self.n_rows = tl.total_s, tl.n
        self.derive()

    def derive(self) -> None:
        """The per-row arrays the runner needs: extruder changes, rows of interest, volumes."""
        tl = self.timeline
        p = tl.program
        rows = tl.rows
        op, flow, layer = p.op[rows], p.flow_mm3_mm[rows], p.layer[rows]
        on = ((op == MOVEL) & (flow > 0)) if self.main else np.zeros(len(rows), dtype=bool)
        ext = np.where(op == SET_TEMP, -1, on).astype(np.int8)
        # extruder state carried through set-point rows: compare with the last real state
        idx = np.where(ext >= 0, np.arange(len(ext)), 0)
        np.maximum.accumulate(idx, out=idx)
        filled = ext[idx]
        change = np.zeros(len(ext), dtype=bool)
        change[1:] = (ext[1:] >= 0) & (filled[1:] != filled[:-1])
        lay = np.zeros(len(ext), dtype=bool)
        if self.main:
            lay[1:] = (layer[1:] >= 0) & (layer[1:] != layer[:-1])
        special = (op == SET_TEMP) | (op == WAIT_TEMP) | (op == RETRACT)
        first = np.zeros(len(ext), dtype=bool)
        first[:1] = True
        self.ext = ext
        self.interesting = np.flatnonzero(first | change | lay | special)
        self.vol_mm3 = np.where(self.main & (op == MOVEL), flow * tl.flow_r * tl.len_mm, 0.0)
        self.cumvol_mm3 = np.concatenate([[0.0], np.cumsum(self.vol_mm3)])

    def row_at(self, tau_s: float) -> int:
        """Local row running at local time ``tau_s`` (within the owned rows)."""
        return int(min(self.timeline.locate(np.array([tau_s]))[0], self.n_rows - 1))

    def cut_at(self, tau_s: float) -> None:
        """End the leg at local time ``tau_s``: the row running then is left unfinished."""
        j = self.row_at(tau_s)
        self.n_rows, self.t_cut = j + 1, float(tau_s)
        self.partial_end = tau_s < self.timeline.t_end_s[j]

    def cut_before(self, j: int) -> None:
        """End the leg when local row ``j`` would start (it owns rows ``0 .. j-1``)."""
        self.n_rows, self.t_cut, self.partial_end = j, float(self.timeline.t_start_s[j]), False

    def cut_after(self, j: int) -> None:
        """End the leg when local row ``j`` completes."""
        self.n_rows, self.t_cut, self.partial_end = j + 1, float(self.timeline.t_end_s[j]), False

    def cursor(self, tau_s: float, final: bool) -> tuple[int, int]:
        """Rows started and rows completed by local time ``tau_s`` (all owned ones when ``final``)."""
        if final:
            return self.n_rows, self.n_rows - int(self.partial_end)
        tl = self.timeline
        ns = int(np.searchsorted(tl.t_start_s, tau_s, side="right"))
        nd = int(np.searchsorted(tl.t_end_s, tau_s, side="right"))
        return min(ns, self.n_rows), min(nd, self.n_rows - int(self.partial_end))

    def end_pose(self) -> PoseSpec:
        """Joints and TCP (plate frame of the leg's program) where the leg ends."""
        tl = self.timeline
        smp = tl.sample(self.t_cut if (self.n_rows or self.placed) else tl.total_s)
        return PoseSpec(np.asarray(smp.q_rad, float), np.asarray(smp.xyz_mm, float),
                        np.asarray(smp.quat_wxyz, float))

    # Saving ---------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """The leg as plain data (the timeline is rebuilt from the spec on restore)."""
        return {"spec": self.spec.to_dict(), "main": self.main, "end_kinds": list(self.end_kinds),
                "built": self.tl is not None, "t0": self.t0, "t_cut": self.t_cut, "n_rows": self.n_rows,
                "partial_end": self.partial_end, "started": self.started, "done": self.done,
                "placed": self.placed}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Leg:
        """A leg with its cursors; the caller rebuilds ``tl`` from ``spec`` and calls :meth:`derive`."""
        return cls(spec_from_dict(d["spec"]), bool(d["main"]), [str(k) for k in d["end_kinds"]],
                   t0=float(d["t0"]), t_cut=float(d["t_cut"]), n_rows=int(d["n_rows"]),
                   partial_end=bool(d["partial_end"]), started=int(d["started"]), done=int(d["done"]),
                   placed=bool(d["placed"]))
