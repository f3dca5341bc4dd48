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
from fabric.wire.errors import ValidationError

__all__ = ["MANUAL_STATES", "FIRMWARE_MIN_EXTRUDE_C", "MAX_JOG_MM", "Jog", "jog_plan", "jog_leg", "extrude_leg"]

MANUAL_STATES = ("idle", "ready", "stopped", "fault")     # not while a print is on (printing, paused, interrupted)
FIRMWARE_MIN_EXTRUDE_C = DEFAULT_MIN_EXTRUDE_C   # with no program loaded: the rule printer firmware applies
MAX_JOG_MM = 200.0                 # the longest jog one command makes


@dataclass(frozen=True)
class Jog:
    """A jog about to be made: from ``start`` (plate frame ``wobj``) to ``xyz_mm`` with joints ``q_rad``."""
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
    xyz = np.asarray(start.xyz_mm, dtype=float) + d
    q = moves.ik_one(wobj, xyz, np.asarray(start.quat_wxyz, dtype=float), np.asarray(start.q_rad, dtype=float))
    return Jog(start, np.asarray(wobj, dtype=float), xyz, q)


def jog_leg(moves: MotionPlanner, jog: Jog, speed_mm_s: float) -> Leg:
    row = {"op": MOVEL, "q_rad": jog.q_rad, "xyz_mm": jog.xyz_mm, "quat_wxyz": jog.start.quat_wxyz,
           "speed_mm_s": float(speed_mm_s)}
    return moves.aux_leg([row], jog.start, jog.wobj, ["jogged"])


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
