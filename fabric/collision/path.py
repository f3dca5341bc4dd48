"""The motion a sweep certifies: a program's (or one joint move's) path as joint-space segments.

The path is exactly what the twin executes (:mod:`fabric.motion.timeline`):

* a linear move (MOVEL) interpolates the joints linearly between the previous
  row's joints and its own; it is one segment, and a point along it at
  fraction ``s`` is ``q_a + s (q_b - q_a)``;
* a joint move (MOVEJ) is a rest-to-rest Ruckig trajectory, timed by
  :func:`fabric.motion.timing.time_program` itself. Rest to rest, every joint
  moves monotonically from its start to its end (``tests/test_collision_path.py``
  checks it), so over any piece of it a joint travels exactly the difference
  of the piece's ends, which is all the motion bounds need. It is cut into
  pieces of at most ``JOINT_PIECE_RAD`` of joint travel; a point at time
  fraction ``s`` is the trajectory at ``s`` times its duration.

The first motion starts from ``q_start`` (the cell's home for a program, as
the supervisor loads it on a station at home). Rows that do not move (waits,
temperatures, retractions) add nothing.

Every segment carries its program row, its move kind (print, travel, approach,
retract, home, joint) and the tip's layer: the layer whose beads (with the
layers it rests on) the nozzle tip may touch: the row's own layer, or the layer
the last extruding row laid when that is later (a lift off the last layer,
the return home).

A live move of the station is one joint move, and for a print restarted at a
layer (start or recover from a layer) also the straight descent that follows
it onto the layer's first point: a linear move, kind ``descent``, whose joints
the twin interpolates linearly like any other linear move.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fabric.motion.program import APPROACH, MOVEJ, MOVEL, RETURN_HOME, Program
from fabric.motion.timing import StartState, time_program

__all__ = ["Segments", "program_segments", "move_segments", "MOVE_KINDS", "JOINT_PIECE_RAD", "LIVE_ROW", "NO_LAYER",
           "START_LAYER"]

JOINT_PIECE_RAD = 0.05      # a joint move is cut into pieces of at most this much travel (sum over joints)
LIVE_ROW = 1 << 62          # the row of a live move: after every bead the twin has laid
NO_LAYER = -1               # a tip layer: the tip may touch nothing
START_LAYER = -100          # a live move's tip layer: the beads the tip rests on where it starts (relabelled so)
MOVE_KINDS = ("print", "travel", "approach", "retract", "home", "joint", "recover", "restart", "descent", "jog",
              "deposit")   # the last: not a move, a bead laid into the part (fabric.sim.material)


@dataclass
class Segments:
    """Joint-space segments in path order: segment ``k`` goes from ``q0[k]`` to ``q1[k]`` (rad), which are
    the points at fractions ``s0[k]`` and ``s1[k]`` of program row ``row[k]``."""

    q0: np.ndarray
    q1: np.ndarray
    row: np.ndarray
    s0: np.ndarray
    s1: np.ndarray
    joint: np.ndarray                    # bool: a piece of a joint move (else a linear move)
    kind: np.ndarray                     # index into MOVE_KINDS
    tip_layer: np.ndarray
    trajectories: dict[int, Any] = field(default_factory=dict)   # row -> Ruckig trajectory of a joint move

    def __post_init__(self) -> None:
        self.dq_abs = np.abs(self.q1 - self.q0)           # joint travel of each segment

    def __len__(self) -> int:
        return len(self.row)

    def q_at(self, k: int, s: float) -> np.ndarray:
        """Joints at fraction ``s`` of segment ``k``'s row (``s0[k] <= s <= s1[k]``)."""
        if self.joint[k]:
            traj = self.trajectories[int(self.row[k])]
            return np.asarray(traj.at_time(float(s) * traj.duration)[0], dtype=float)
        span = self.s1[k] - self.s0[k]
        f = 0.0 if span <= 0 else (s - self.s0[k]) / span
        return self.q0[k] + (self.q1[k] - self.q0[k]) * f

    def runs(self, key: np.ndarray) -> list[tuple[int, int]]:
        """Maximal ranges [a, b) of segments with the same value of ``key`` (per segment)."""
        if len(self) == 0:
            return []
        cut = np.flatnonzero(key[1:] != key[:-1]) + 1
        edges = np.concatenate([[0], cut, [len(self)]])
        return [(int(a), int(b)) for a, b in itertools.pairwise(edges)]


def joint_trajectory(robot: Any, q_from: np.ndarray, q_to: np.ndarray, vel_r: float) -> Any:
    """The Ruckig trajectory the twin runs for a joint move (timed by ``time_program`` on a one-row
    program starting at rest at ``q_from``)."""
    prog = Program.empty(1, nq=len(q_to))
    prog.op[0], prog.q_rad[0], prog.vel_r[0] = MOVEJ, q_to, vel_r
    tl = time_program(prog, robot, start_state=StartState(np.asarray(q_from, float), np.zeros(3),
                                                          np.array([1.0, 0.0, 0.0, 0.0])))
    return tl.joint_traj[0]


def _joint_pieces(traj: Any, q_from: np.ndarray, q_to: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(fractions (K+1,), joints (K+1, nq)) cutting a joint move into pieces of <= JOINT_PIECE_RAD."""
    n = max(1, int(np.ceil(np.abs(q_to - q_from).sum() / JOINT_PIECE_RAD)))
    s = np.linspace(0.0, 1.0, n + 1)
    q = np.array([traj.at_time(float(f) * traj.duration)[0] for f in s], dtype=float)
    q[0], q[-1] = q_from, q_to
    return s, q


def tip_layers(program: Program) -> np.ndarray:
    """Per row: the layer the tip may touch (its beads and those it rests on): the row's own layer, or the
    last extruding row's layer when later."""
    laid = np.where((program.op == MOVEL) & (program.flow_mm3_mm > 0), program.layer, -1)
    return np.maximum(program.layer, np.maximum.accumulate(laid) if len(laid) else laid)


def move_kinds(program: Program) -> np.ndarray:
    """Per row: index into MOVE_KINDS (joint moves: approach / home / joint; linear: print when extruding,
    approach before the print, retract after it, travel otherwise)."""
    sec, op = program.section, program.op
    kind = np.full(len(program), MOVE_KINDS.index("travel"))
    kind[(op == MOVEL) & (program.flow_mm3_mm > 0)] = MOVE_KINDS.index("print")
    kind[(op == MOVEL) & (sec == APPROACH)] = MOVE_KINDS.index("approach")
    kind[(op == MOVEL) & (sec == RETURN_HOME)] = MOVE_KINDS.index("retract")
    kind[op == MOVEJ] = MOVE_KINDS.index("joint")
    kind[(op == MOVEJ) & (sec == APPROACH)] = MOVE_KINDS.index("approach")
    kind[(op == MOVEJ) & (sec == RETURN_HOME)] = MOVE_KINDS.index("home")
    return kind


def program_segments(program: Program, robot: Any, q_start: np.ndarray) -> Segments:
    """The path of ``program`` from joints ``q_start``."""
    motion = np.flatnonzero(program.op <= MOVEL)
    q = program.q_rad
    prev = np.vstack([np.asarray(q_start, dtype=float)[None], q[motion[:-1]]]) if len(motion) else q[:0]
    moved = np.any(q[motion] != prev, axis=1)
    motion, prev = motion[moved], prev[moved]
    kinds, tips = move_kinds(program), tip_layers(program)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("q0", "q1", "row", "s0", "s1", "joint")}
    trajectories: dict[int, Any] = {}
    joint_rows = motion[program.op[motion] == MOVEJ]
    # linear moves: one segment each; joint moves: their Ruckig pieces, spliced in at their rows
    cuts = np.searchsorted(motion, joint_rows)
    start = 0
    for j, row in zip(cuts.tolist(), joint_rows.tolist(), strict=True):
        _linear(parts, motion[start:j], prev[start:j], q)
        traj = joint_trajectory(robot, prev[j], q[row], float(program.vel_r[row]))
        trajectories[row] = traj
        s, qs = _joint_pieces(traj, prev[j], q[row])
        n = len(s) - 1
        for name, val in (("q0", qs[:-1]), ("q1", qs[1:]), ("row", np.full(n, row)), ("s0", s[:-1]),
                          ("s1", s[1:]), ("joint", np.ones(n, bool))):
            parts[name].append(val)
        start = j + 1
    _linear(parts, motion[start:], prev[start:], q)
    nq = q.shape[1]
    cat = {k: np.concatenate(v) if v else np.zeros((0, nq) if k in ("q0", "q1") else 0) for k, v in parts.items()}
    rows = cat["row"].astype(np.int64)
    return Segments(cat["q0"].reshape(-1, nq), cat["q1"].reshape(-1, nq), rows, cat["s0"].astype(float),
                    cat["s1"].astype(float), cat["joint"].astype(bool), kinds[rows], tips[rows], trajectories)


def _linear(parts: dict[str, list[np.ndarray]], rows: np.ndarray, prev: np.ndarray, q: np.ndarray) -> None:
    n = len(rows)
    for name, val in (("q0", prev), ("q1", q[rows]), ("row", rows), ("s0", np.zeros(n)), ("s1", np.ones(n)),
                      ("joint", np.zeros(n, bool))):
        parts[name].append(val)


def move_segments(robot: Any, q_from: np.ndarray, q_to: np.ndarray, vel_r: float, kind: str = "joint",
                  tip_layer: int = -1, q_down: np.ndarray | None = None, down_tip_layer: int = NO_LAYER) -> Segments:
    """One joint move the station is about to make (row ``LIVE_ROW``: after every bead laid so far); with
    ``q_down``, then a straight descent from ``q_to`` to ``q_down`` (one linear segment of kind ``descent``,
    its tip's layer ``down_tip_layer``; of kind ``jog`` when ``kind`` is: a jog is that straight move alone)."""
    q_from, q_to = np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)
    nq = len(q_from)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("q0", "q1", "s0", "s1", "joint", "kind", "tip")}
    trajectories: dict[int, Any] = {}

    def add(q0: np.ndarray, q1: np.ndarray, s0: np.ndarray, s1: np.ndarray, joint: bool, move: str,
            tip: int) -> None:
        n = len(s0)
        for name, val in (("q0", q0), ("q1", q1), ("s0", s0), ("s1", s1), ("joint", np.full(n, joint)),
                          ("kind", np.full(n, MOVE_KINDS.index(move))), ("tip", np.full(n, tip))):
            parts[name].append(val)

    if not np.all(q_from == q_to):
        traj = trajectories[LIVE_ROW] = joint_trajectory(robot, q_from, q_to, vel_r)
        s, qs = _joint_pieces(traj, q_from, q_to)
        add(qs[:-1], qs[1:], s[:-1], s[1:], True, kind, tip_layer)
    if q_down is not None and not np.all(np.asarray(q_down, dtype=float) == q_to):
        add(q_to[None], np.asarray(q_down, dtype=float)[None], np.zeros(1), np.ones(1), False,
            "jog" if kind == "jog" else "descent", down_tip_layer)
    cat = {k: np.concatenate(v) if v else np.zeros((0, nq) if k in ("q0", "q1") else 0) for k, v in parts.items()}
    return Segments(cat["q0"].reshape(-1, nq), cat["q1"].reshape(-1, nq), np.full(len(cat["s0"]), LIVE_ROW,
                    dtype=np.int64), cat["s0"].astype(float), cat["s1"].astype(float), cat["joint"].astype(bool),
                    cat["kind"].astype(np.int64), cat["tip"].astype(np.int64), trajectories)
