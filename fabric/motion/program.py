"""The robot program the station executes: columnar arrays, one row per instruction.

A program is the paper's structure made explicit: an *Approach* section (joint
moves to above the plate), the *Print* section (linear moves along the
toolpath, with the extruder's flow per move: the paper's "Filament on/off"
module falls out of where ``flow_mm3_mm`` turns non-zero and back to zero),
and *Return home* (joint moves to the home joints).

Rows are instructions. Motion rows (MOVEJ/MOVEL) carry the joint target and
the TCP target; non-motion rows (waits, temperatures, retractions) repeat the
previous row's joints and TCP so that every row has a well-defined pose.

Frames: ``xyz_mm`` and ``quat_wxyz`` are the TCP in the *plate frame* (the work
object); ``q_rad`` are the joints solved for the work object recorded in
``wobj`` (4x4, plate frame in the robot base frame, metres-free: mm).

Joints: ``q_rad`` has one column per joint of the arm (``nq``: 6 for the
IRB 140, KR 6 and UR arms, 7 for the Panda). ``COLUMNS`` lists it with the
6-axis shape; :func:`column_spec` gives the spec of any ``nq``, and a program
checks that every row has the same number of joints.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

# Instruction codes (``op`` column).
MOVEJ, MOVEL, WAIT, SET_TEMP, WAIT_TEMP, RETRACT = 0, 1, 2, 3, 4, 5
OP_NAMES = {MOVEJ: "MoveJ", MOVEL: "MoveL", WAIT: "Wait", SET_TEMP: "SetTemp",
            WAIT_TEMP: "WaitTemp", RETRACT: "Retract"}

# Section codes (``section`` column): the paper's sub-programs.
APPROACH, PRINT, RETURN_HOME = 0, 1, 2
SECTION_NAMES = {APPROACH: "Approach", PRINT: "Print", RETURN_HOME: "ReturnHome"}

# Heater ids (``aux`` column of SET_TEMP / WAIT_TEMP rows).
NOZZLE, BED = 0, 1

JOINTS = "q_rad"                   # the one column whose width is the arm's number of joints
DEFAULT_NQ = 6

COLUMNS: dict[str, tuple[str, tuple[int, ...]]] = {
    # name: (dtype, trailing shape)
    "op": ("u1", ()),
    "section": ("u1", ()),
    "q_rad": ("f8", (6,)),
    "xyz_mm": ("f8", (3,)),
    "quat_wxyz": ("f8", (4,)),
    "speed_mm_s": ("f8", ()),     # MOVEL: programmed TCP speed
    "vel_r": ("f8", ()),          # MOVEJ: fraction of the joints' velocity limits
    "zone_mm": ("f8", ()),        # 0 = fine (stop point)
    "flow_mm3_mm": ("f8", ()),    # deposited volume per mm of TCP path (0 = extruder off)
    "value": ("f8", ()),          # WAIT: seconds; *_TEMP: deg C; RETRACT: filament mm (<0 retract)
    "aux": ("i2", ()),            # *_TEMP: heater id
    "gcode_line": ("i8", ()),     # source line, -1 when none
    "layer": ("i4", ()),          # layer index, -1 outside the print
}


def column_spec(nq: int = DEFAULT_NQ) -> dict[str, tuple[str, tuple[int, ...]]]:
    """The program columns of an arm with ``nq`` joints (``COLUMNS`` with ``q_rad`` (nq,))."""
    if not 1 <= int(nq) <= 32:
        raise ValueError(f"an arm has 1..32 joints, not {nq}")
    return {**COLUMNS, JOINTS: ("f8", (int(nq),))}


@dataclass
class Program:
    """A robot program in columnar form (see module docstring for meaning)."""

    op: np.ndarray
    section: np.ndarray
    q_rad: np.ndarray
    xyz_mm: np.ndarray
    quat_wxyz: np.ndarray
    speed_mm_s: np.ndarray
    vel_r: np.ndarray
    zone_mm: np.ndarray
    flow_mm3_mm: np.ndarray
    value: np.ndarray
    aux: np.ndarray
    gcode_line: np.ndarray
    layer: np.ndarray
    wobj: np.ndarray = field(default_factory=lambda: np.eye(4))
    meta: dict[str, Any] = field(default_factory=dict)
    # columns mapped from files (fabric.motion.program_file): gives back the pages of rows read through
    pager: Any = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        n = len(self.op)
        q = np.asarray(self.q_rad)
        spec = column_spec(q.shape[1] if q.ndim == 2 and q.shape[1] >= 1 else DEFAULT_NQ)
        for name, (dtype, shape) in spec.items():
            arr = np.ascontiguousarray(getattr(self, name), dtype=dtype)
            if arr.shape != (n, *shape):
                raise ValueError(f"program column {name}: shape {arr.shape}, expected {(n, *shape)}")
            setattr(self, name, arr)
        self.wobj = np.asarray(self.wobj, dtype="f8").reshape(4, 4)

    def __len__(self) -> int:
        return len(self.op)

    @property
    def nq(self) -> int:
        """The number of joints per row (the width of ``q_rad``)."""
        return int(self.q_rad.shape[1])

    def release_pages(self, start: int = 0, stop: int | None = None) -> None:
        """Done with rows ``[start, stop)`` for now: a program mapped from files gives their pages back to the
        OS (they stay readable, from the page cache); a program in memory does nothing. Code that walks a
        program in blocks calls this behind itself, so a 17 M-row program never becomes resident whole."""
        if self.pager is not None:
            self.pager.release(start, stop)

    @classmethod
    def empty(cls, n: int, nq: int = DEFAULT_NQ, **meta: Any) -> Program:
        """A program of ``n`` zeroed rows of ``nq`` joints (quaternions identity, lines/layers -1)."""
        cols = {name: np.zeros((n, *shape), dtype=dtype) for name, (dtype, shape) in column_spec(nq).items()}
        cols["quat_wxyz"][:, 0] = 1.0
        cols["gcode_line"][:] = -1
        cols["layer"][:] = -1
        return cls(**cols, meta=dict(meta))

    @classmethod
    def concat(cls, parts: list[Program]) -> Program:
        """Join programs (the first one's ``wobj`` and merged ``meta``)."""
        cols = {name: np.concatenate([getattr(p, name) for p in parts]) for name in COLUMNS}
        meta: dict[str, Any] = {}
        for p in parts:
            meta.update(p.meta)
        return cls(**cols, wobj=parts[0].wobj, meta=meta)

    def slice(self, start: int, stop: int | None = None) -> Program:
        cols = {name: getattr(self, name)[start:stop] for name in COLUMNS}
        return Program(**cols, wobj=self.wobj, meta=dict(self.meta))

    def columns(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in COLUMNS}

    # Derived views -----------------------------------------------------

    def is_motion(self) -> np.ndarray:
        return self.op <= MOVEL

    def extruder_events(self) -> tuple[np.ndarray, np.ndarray]:
        """Rows where the extruder turns on and off: the paper's Filament on/off module."""
        on = self.flow_mm3_mm > 0
        prev = np.concatenate([[False], on[:-1]])
        return np.flatnonzero(on & ~prev), np.flatnonzero(~on & prev & self.is_motion())

    def section_bounds(self) -> dict[str, tuple[int, int]]:
        """Row range [start, stop) of each section present (found in blocks of rows)."""
        found: dict[str, tuple[int, int]] = {}
        block = 1 << 20
        for a in range(0, len(self), block):
            sec = self.section[a:a + block]
            for code, name in SECTION_NAMES.items():
                idx = np.flatnonzero(sec == code)
                if len(idx):
                    lo, _hi = found.get(name, (a + int(idx[0]), 0))
                    found[name] = (lo, a + int(idx[-1]) + 1)
        return {name: found[name] for name in SECTION_NAMES.values() if name in found}

    def path_length_mm(self) -> np.ndarray:
        """TCP path length of each row's move (0 for the first row and non-motion rows)."""
        d = np.zeros(len(self))
        if len(self) > 1:
            d[1:] = np.linalg.norm(np.diff(self.xyz_mm, axis=0), axis=1)
        d[~self.is_motion()] = 0.0
        return d

    def deposited_volume_mm3(self) -> float:
        """Volume the program deposits (flow x path length over linear moves)."""
        return float(np.sum(self.flow_mm3_mm * self.path_length_mm() * (self.op == MOVEL)))


def mini_program(rows: list[dict[str, Any]], wobj: np.ndarray, nq: int | None = None) -> Program:
    """A small program from explicit rows (column name -> value; others as ``Program.empty``):
    the twin's own moves (lift, lower, retract, home) are timed by the same model."""
    if nq is None:                   # the arm's joints: from the first row that has them
        nq = next((len(np.atleast_1d(r[JOINTS])) for r in rows if JOINTS in r), DEFAULT_NQ)
    p = Program.empty(len(rows), nq=nq)
    p.wobj = np.asarray(wobj, dtype=float).reshape(4, 4)
    for i, row in enumerate(rows):
        for name, val in row.items():
            getattr(p, name)[i] = val
    return p
