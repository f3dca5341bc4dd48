"""Moves by hand while nothing prints: jog the nozzle in the plate frame, push or pull filament.

A jog is one straight move from where the robot rests (or where its queued motion ends) by a vector in the
plate frame, the nozzle's orientation kept, timed like any of the twin's own moves; it is split as the
planner splits a program's linear moves, so that the nozzle keeps to the line, not to the curve its
interpolated joints would take. A manual extrude keeps
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
from fabric.motion.program import MOVEL, RETRACT, WAIT, Program, mini_program
from fabric.planning.chunk_ik import JUMP_DEG
from fabric.planning.options import PlanOptions
from fabric.planning.refine import PrevRow, refine_linear
from fabric.robot.kinematics import IK_OK, ik_reason
from fabric.schemas.states import FREE_STATION_STATES
from fabric.sim.legs import Leg, PoseSpec
from fabric.sim.moves import MotionPlanner
from fabric.sim.types import IK_ACCEPT
from fabric.wire.errors import UnreachableError, ValidationError

__all__ = ["MANUAL_STATES", "FIRMWARE_MIN_EXTRUDE_C", "MAX_JOG_MM", "JOG_LINE_TOL_MM", "Jog", "jog_plan", "jog_leg",
           "extrude_leg"]

MANUAL_STATES = FREE_STATION_STATES     # not while a print is on (printing, paused, interrupted)
FIRMWARE_MIN_EXTRUDE_C = DEFAULT_MIN_EXTRUDE_C   # with no program loaded: the rule printer firmware applies
MAX_JOG_MM = 200.0                 # the longest jog one command makes


JOG_LINE_TOL_MM = PlanOptions.linear_tol_mm   # the jog's interpolated joints keep this close to its line, as a
#                                               planned program's linear moves do (fabric.planning.refine)


@dataclass(frozen=True)
class Jog:
    """A jog about to be made from ``start`` (plate frame ``wobj``): its ``rows``, one linear move to the end,
    split by :func:`fabric.planning.refine.refine_linear` where interpolating the joints would leave the
    straight line by more than ``JOG_LINE_TOL_MM`` (the pieces pass through their points; the end is a stop)."""
    start: PoseSpec
    wobj: np.ndarray
    rows: Program

    @property
    def q_rad(self) -> np.ndarray:
        """Joints (M, nq) of each point of the jog, the last its end."""
        return self.rows.q_rad

    @property
    def xyz_mm(self) -> np.ndarray:
        """Plate-frame TCP (M, 3) of each point of the jog, the last its end."""
        return self.rows.xyz_mm


def jog_plan(moves: MotionPlanner, dxyz_mm: list[float] | np.ndarray) -> Jog:
    """Where a jog by ``dxyz_mm`` goes (UnreachableError when the robot cannot get there, or its straight
    line needs the arm to change its configuration)."""
    d = np.asarray(dxyz_mm, dtype=float).reshape(3)
    length = float(np.linalg.norm(d))
    if not np.isfinite(length) or length == 0.0:
        raise ValidationError("a jog needs a non-zero, finite distance", field="dxyz_mm", value=d.tolist())
    if length > MAX_JOG_MM:
        raise ValidationError(f"a jog of {length:.1f} mm is longer than {MAX_JOG_MM:g} mm: make it in steps",
                              field="dxyz_mm", value=d.tolist())
    start, wobj = moves.queue_end()
    wobj = np.asarray(wobj, dtype=float)
    a, quat = np.asarray(start.xyz_mm, dtype=float), np.asarray(start.quat_wxyz, dtype=float)
    q0 = np.asarray(start.q_rad, dtype=float)
    q1 = moves.ik_one(wobj, a + d, quat, q0)
    move = mini_program([{"op": MOVEL, "q_rad": q1, "xyz_mm": a + d, "quat_wxyz": quat}], wobj, nq=len(q0))
    ref = refine_linear(move, np.array([IK_OK], np.uint8), np.zeros(1), moves.robot, JOG_LINE_TOL_MM,
                        np.radians(JUMP_DEG), PrevRow(a, quat, q0, IK_OK))
    bad = np.flatnonzero(~np.isin(ref.status, IK_ACCEPT))
    if len(bad):
        at = ref.program.xyz_mm[bad[0]]
        raise UnreachableError(f"the jog's straight line at {np.round(at, 1).tolist()} mm (plate frame) is not "
                               f"a motion of the arm ({ik_reason(int(ref.status[bad[0]]))}): jog in other steps",
                               reason=ik_reason(int(ref.status[bad[0]])), gcode_line=-1, xyz_mm=at.tolist())
    return Jog(start, wobj, ref.program)


def jog_leg(moves: MotionPlanner, jog: Jog, speed_mm_s: float) -> Leg:
    r = jog.rows
    rows = [{"op": MOVEL, "q_rad": r.q_rad[i], "xyz_mm": r.xyz_mm[i], "quat_wxyz": r.quat_wxyz[i],
             "speed_mm_s": float(speed_mm_s), "zone_mm": r.zone_mm[i]} for i in range(len(r))]
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
