"""The station-ready checklist: each item passes or fails with a reason."""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from fabric import schemas as s
from fabric.errors import FabricError
from fabric.keys import SERVICES
from fabric.motion.program import SET_TEMP, NOZZLE

if TYPE_CHECKING:
    from fabric.services.station import StationService

TEMP_TOLERANCE_C = 5.0


def ready_report(svc: "StationService") -> s.ReadyReport:
    """Services alive, program planned and collision-free, robot at a known pose, extruder hot, no fault."""
    checks: list[s.Check] = []
    alive = svc.client.alive(timeout=2.0)
    dead = [n for n in SERVICES if not alive.get(n)]
    checks.append(s.Check(name="services alive", ok=not dead,
                          detail="all " + str(len(SERVICES)) if not dead else "down: " + ", ".join(dead)))

    program_ok = bool(svc.program_id)
    checks.append(s.Check(name="program planned and loaded", ok=program_ok,
                          detail=svc.program_id[:12] if program_ok else "no program loaded"))

    if program_ok and svc.collision_report is None:
        try:
            svc.collision_report = svc.client.check(s.CollisionRequest(program_id=svc.program_id))
        except FabricError as err:
            checks.append(s.Check(name="program collision-free", ok=False, detail=f"check failed: {err.message}"))
    rep = svc.collision_report
    if rep is not None:
        hit = rep.first_hit
        checks.append(s.Check(name="program collision-free", ok=hit is None,
                              detail=f"min clearance {rep.min_distance_mm:.1f} mm" if hit is None else
                              f"{hit.body_a} <-> {hit.body_b} at line {hit.gcode_line}"))
    elif not any(c.name == "program collision-free" for c in checks):
        checks.append(s.Check(name="program collision-free", ok=False, detail="not checked (no program)"))

    with svc.lock:
        q = svc.twin.pose().q_rad
        robot = svc.cell.robot
        known = bool(np.all(np.isfinite(q)) and robot.within_limits(q[None, :])[0])
        at_home = bool(np.allclose(q, svc.cell.home_q_rad, atol=1e-3))
        checks.append(s.Check(name="robot at a known pose", ok=known,
                              detail="at home" if at_home else ("within limits" if known else "outside its limits")))
        temps = svc.twin.temps()
        program = svc.twin.program
        need_c = _print_temp_c(program) if program is not None else None
        if need_c is None:
            checks.append(s.Check(name="extruder at temperature", ok=False, detail="no print temperature known"))
        else:
            hot = abs(temps.nozzle_c - need_c) <= TEMP_TOLERANCE_C
            checks.append(s.Check(name="extruder at temperature", ok=hot,
                                  detail=f"nozzle {temps.nozzle_c:.0f} C, print needs {need_c:.0f} C"
                                  + ("" if hot else " (the program waits for it at the start)")))
        fault = svc.twin.state == "fault"
        checks.append(s.Check(name="no fault", ok=not fault, detail=svc.twin.reason if fault else ""))
    return s.ReadyReport(ready=all(c.ok for c in checks), checks=checks)


def _print_temp_c(program) -> float | None:
    rows = np.flatnonzero((program.op == SET_TEMP) & (program.aux == NOZZLE) & (program.value > 0))
    return float(program.value[rows[0]]) if len(rows) else None
