"""The station's commands by hand while nothing prints: ``jog`` (a straight move of the nozzle, certified
against the part on the plate first) and ``extrude`` (filament pushed or pulled, the robot still).

A feature of the station built on its public surface only (Klipper's ``extras``): :class:`ManualCommands`
registers its two commands on the station, and a jog is a checked change of the station's command runner
(``fabric.services.station_commands``) like ``home``: planned in a step, each straight piece certified
outside the writer, made only if nothing changed meanwhile, checkpointed by the runner.
"""
from __future__ import annotations

import numpy as np

from fabric import schemas as s
from fabric.services.station_commands import Planned, StationSurface

__all__ = ["ManualCommands"]


class ManualCommands:
    """``jog`` and ``extrude`` of one station (registered on it when made)."""

    def __init__(self, station: StationSurface) -> None:
        self.station = station
        station.register_command("jog", self.cmd_jog)
        station.register_command("extrude", self.cmd_extrude)

    def cmd_jog(self, req: s.JogRequest) -> s.Ack:
        st = self.station
        d = [float(v) for v in req.dxyz_mm]
        what = f"the jog by ({d[0]:g}, {d[1]:g}, {d[2]:g}) mm"

        def plan() -> Planned[None]:
            q_now, q_points = st.twin.jog_move(d)
            pieces = zip(np.vstack([q_now, q_points[:-1]]), q_points, strict=True)    # each straight piece
            return Planned([st.move(q_from, q_from, what, "jog", descent=(q_to, -1)) for q_from, q_to in pieces],
                           None, what)

        def act(_: Planned[None]) -> s.Ack:
            st.twin.jog(d, req.speed_mm_s)
            return st.ack(f"jogging by ({d[0]:g}, {d[1]:g}, {d[2]:g}) mm at {req.speed_mm_s:g} mm/s "
                          f"(collision-checked)")
        return st.commands.checked("jog", plan, act)

    def cmd_extrude(self, req: s.ExtrudeRequest) -> s.Ack:
        st = self.station

        def act() -> s.Ack:
            st.twin.extrude(req.length_mm, req.speed_mm_s)
            verb = "extruding" if req.length_mm > 0 else "retracting"
            return st.ack(f"{verb} {abs(req.length_mm):g} mm of filament at {req.speed_mm_s:g} mm/s")
        return st.commands.change(act)
