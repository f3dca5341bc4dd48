"""The station's commands by hand while nothing prints: ``jog`` (a straight move of the nozzle, certified
against the part on the plate first) and ``extrude`` (filament pushed or pulled, the robot still).

Like ``home``, a jog is two steps of the station's writer around the collision check: the first reads the
move and a stamp, the check runs in the handler's thread, the second makes the move only if nothing changed.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from fabric import schemas as s

if TYPE_CHECKING:
    from fabric.services.station import StationService

__all__ = ["jog", "extrude"]


def jog(station: StationService, req: s.JogRequest) -> s.Ack:
    d = [float(v) for v in req.dxyz_mm]
    what = f"the jog by ({d[0]:g}, {d[1]:g}, {d[2]:g}) mm"

    def plan() -> tuple[np.ndarray, np.ndarray, tuple]:
        q_now, q_to = station.twin.jog_move(d)
        return q_now, q_to, station._stamp()

    def act() -> s.Ack:
        station._still(stamp, what, "jog")
        station.twin.jog(d, req.speed_mm_s)
        station._changed()
        return station._ack(f"jogging by ({d[0]:g}, {d[1]:g}, {d[2]:g}) mm at {req.speed_mm_s:g} mm/s "
                            f"(collision-checked)")

    q_now, q_points, stamp = station._step(plan)
    for q_from, q_to in zip(np.vstack([q_now, q_points[:-1]]), q_points, strict=True):   # each piece, in turn
        station._check_move(q_from, q_from, what, descent=(q_to, -1), kind="jog")
    return station._step(act)


def extrude(station: StationService, req: s.ExtrudeRequest) -> s.Ack:
    def act() -> s.Ack:
        station.twin.extrude(req.length_mm, req.speed_mm_s)
        station._changed()
        verb = "extruding" if req.length_mm > 0 else "retracting"
        return station._ack(f"{verb} {abs(req.length_mm):g} mm of filament at {req.speed_mm_s:g} mm/s")
    return station._step(act)
