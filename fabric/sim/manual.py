"""Moves by hand while nothing prints: jog the nozzle in the plate frame, push or pull filament.

A jog is one straight move from where the robot rests (or where its queued motion ends) by a vector in the
plate frame, the nozzle's orientation kept, timed like any of the twin's own moves. A manual extrude keeps
the robot still and moves the filament: a wait for the feed (the length at the asked feed rate), then the
filament move itself, which the extrusion readout counts as filament pushed (a purge is not a bead: it is
not part of the part on the plate). Both end with an event: ``jogged`` (where the nozzle is) and
``extruded`` (how much filament moved). The length travels in the leg's end kind (``extruded:<mm>``), so
that a leg restored from a checkpoint still reports it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabric.motion.cold import DEFAULT_MIN_EXTRUDE_C
from fabric.motion.program import MOVEL, RETRACT, WAIT
from fabric.sim.legs import Leg, PoseSpec
from fabric.sim.moves import MotionPlanner
from fabric.wire.errors import UnreachableError, ValidationError

__all__ = ["MANUAL_STATES", "FIRMWARE_MIN_EXTRUDE_C", "MAX_JOG_MM", "JOG_LINE_TOL_MM", "Jog", "jog_plan", "jog_leg",
           "extrude_leg"]

MANUAL_STATES = ("idle", "ready", "stopped", "fault")     # not while a print is on (printing, paused, interrupted)
FIRMWARE_MIN_EXTRUDE_C = DEFAULT_MIN_EXTRUDE_C   # with no program loaded: the rule printer firmware applies
MAX_JOG_MM = 200.0                 # the longest jog one command makes


JOG_LINE_TOL_MM = 0.1              # the jog's joints, interpolated, keep this close to its straight line
JOG_ROUNDS = 4                     # measure-and-split passes at most
JOG_JUMP_RAD = np.radians(45.0)    # a piece whose joints are further from the interpolated ones needs a new
#                                    configuration on the line: refused
JOG_PASS_ZONE_MM = 0.01            # the zone of the points between pieces: passed, not stopped at (the end is
#                                    a stop), as the planner's split moves (fabric.planning.refine.PASS_ZONE_MM)


@dataclass(frozen=True)
class Jog:
    """A jog about to be made: from ``start`` (plate frame ``wobj``) through the points ``xyz_mm`` (M, 3), the
    last its end, with joints ``q_rad`` (M, nq): pieces short enough that interpolating the joints between
    them keeps the nozzle within ``JOG_LINE_TOL_MM`` of the straight line (one piece when that holds)."""
    start: PoseSpec
    wobj: np.ndarray
    xyz_mm: np.ndarray
    q_rad: np.ndarray


def jog_plan(moves: MotionPlanner, dxyz_mm: list[float] | np.ndarray) -> Jog:
    """Where a jog by ``dxyz_mm`` goes (UnreachableError when the robot cannot get there)."""
    d = np.asarray(dxyz_mm, dtype=float).reshape(3)
    length = float(np.linalg.norm(d))
    if not np.isfinite(length) or length == 0.0:
        raise ValidationError("a jog needs a non-zero, finite distance", field="dxyz_mm", value=d.tolist())
    if length > MAX_JOG_MM:
        raise ValidationError(f"a jog of {length:.1f} mm is longer than {MAX_JOG_MM:g} mm: make it in steps",
                              field="dxyz_mm", value=d.tolist())
    start, wobj = moves.queue_end()
    wobj = np.asarray(wobj, dtype=float)
    a = np.asarray(start.xyz_mm, dtype=float)
    quat = np.asarray(start.quat_wxyz, dtype=float)
    q0 = np.asarray(start.q_rad, dtype=float)
    q1 = moves.ik_one(wobj, a + d, quat, q0)
    f, q = _straight(moves, wobj, a, d, quat, q0, q1)
    return Jog(start, wobj, a + f[1:, None] * d, q[1:])


def _straight(moves: MotionPlanner, wobj: np.ndarray, a: np.ndarray, d: np.ndarray, quat: np.ndarray,
              q0: np.ndarray, q1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points along the jog (fractions ``f`` (M + 1,) of ``d`` from ``a``, 0 and 1 included) and their joints
    (M + 1, nq), so that each piece's interpolated joints keep the TCP within ``JOG_LINE_TOL_MM`` of the line
    half-way (as ``fabric.planning.refine`` splits a program's linear moves): a piece straying further is cut
    in ``ceil(sqrt(sag / tol))`` (the sag falls with the square of the length), its new points solved on the
    line nearest the interpolated joints."""
    robot = moves.robot
    R, t = wobj[:3, :3], wobj[:3, 3]
    f, q = np.array([0.0, 1.0]), np.stack([q0, q1])
    for _ in range(JOG_ROUNDS):
        half = robot.tcp_xyz_mm(0.5 * (q[:-1] + q[1:]))
        mid = (a + 0.5 * (f[:-1] + f[1:])[:, None] * d) @ R.T + t
        sag = np.linalg.norm(half - mid, axis=1)
        far = np.flatnonzero(sag > 0.8 * JOG_LINE_TOL_MM)
        if not len(far):
            break
        fs, qs = [f[:1]], [q[:1]]
        for k in range(len(f) - 1):
            if k in far:
                m = int(np.ceil(np.sqrt(sag[k] / (0.8 * JOG_LINE_TOL_MM))))
                for s in np.arange(1, m) / m:
                    fk = f[k] + s * (f[k + 1] - f[k])
                    lerp = q[k] + s * (q[k + 1] - q[k])
                    qk = moves.ik_one(wobj, a + fk * d, quat, lerp)
                    if np.max(np.abs(qk - lerp)) > JOG_JUMP_RAD:
                        raise UnreachableError(
                            f"the jog's straight line at {np.round(a + fk * d, 1).tolist()} mm (plate frame) needs "
                            "the arm to change its configuration: jog in other steps", reason="joint_jump",
                            gcode_line=-1, xyz_mm=(a + fk * d).tolist())
                    fs.append(np.array([fk]))
                    qs.append(qk[None])
            fs.append(f[k + 1:k + 2])
            qs.append(q[k + 1:k + 2])
        f, q = np.concatenate(fs), np.concatenate(qs)
    return f, q


def jog_leg(moves: MotionPlanner, jog: Jog, speed_mm_s: float) -> Leg:
    n = len(jog.q_rad)
    rows = [{"op": MOVEL, "q_rad": jog.q_rad[i], "xyz_mm": jog.xyz_mm[i], "quat_wxyz": jog.start.quat_wxyz,
             "speed_mm_s": float(speed_mm_s), "zone_mm": 0.0 if i == n - 1 else JOG_PASS_ZONE_MM} for i in range(n)]
    return moves.aux_leg(rows, jog.start, jog.wobj, ["jogged"])


def extrude_leg(moves: MotionPlanner, length_mm: float, feed_mm_s: float, retract_speed_mm_s: float) -> Leg:
    """The robot still, ``length_mm`` of filament pushed (> 0) or pulled back (< 0) at ``feed_mm_s``."""
    if not np.isfinite(length_mm) or length_mm == 0.0:
        raise ValidationError("give a non-zero filament length", field="length_mm", value=length_mm)
    start, wobj = moves.queue_end()
    here = {"q_rad": start.q_rad, "xyz_mm": start.xyz_mm, "quat_wxyz": start.quat_wxyz}
    rows = []
    wait_s = abs(length_mm) / feed_mm_s - abs(length_mm) / retract_speed_mm_s   # the filament move is timed too
    if wait_s > 0:
        rows.append({"op": WAIT, "value": wait_s, **here})
    rows.append({"op": RETRACT, "value": float(length_mm), **here})
    return moves.aux_leg(rows, start, wobj, [f"extruded:{float(length_mm)!r}"])
