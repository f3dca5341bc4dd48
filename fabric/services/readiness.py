"""The station-ready checklist: a pure function of facts the station gathers; each item passes or fails with why."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabric import schemas as s
from fabric.motion.program import NOZZLE, SET_TEMP, Program
from fabric.schemas.states import Station
from fabric.wire.keys import SERVICES

__all__ = ["ReadyFacts", "ready_report", "print_temp_c", "TEMP_TOLERANCE_C"]

TEMP_TOLERANCE_C = 5.0


@dataclass(frozen=True)
class ReadyFacts:
    """What the checklist judges, as plain values (the station asks the fabric and reads the twin)."""

    alive: dict[str, bool]                     # service -> holds a liveliness token
    program_id: str                            # the loaded program ("" when none)
    collisions: s.CollisionReport | None       # the loaded program's sweep, when one was made
    collision_error: str                       # why the sweep could not be made ("" when it was, or not tried)
    pose_known: bool                           # joints finite and within their limits
    at_home: bool
    nozzle_c: float
    print_temp_c: float | None                 # nozzle temperature the program sets (None: no program / none set)
    state: Station                             # the twin's state
    reason: str = ""                           # why it is in that state (the fault's reason)
    plate: str = ""                            # what is on the plate ("" when it is clear)
    robot: s.RobotStatus | None = None         # the robot the station drives (None: the twin alone)


def ready_report(facts: ReadyFacts) -> s.ReadyReport:
    """Services alive, program planned and collision-free, robot at a known pose, plate clear, no fault; the
    nozzle temperature is said (never a blocker)."""
    checks = [_services(facts), _program(facts), _collisions(facts), _pose(facts), _plate(facts),
              _temperature(facts), _fault(facts)] + ([_robot(facts.robot)] if facts.robot is not None else [])
    return s.ReadyReport(ready=all(c.ok for c in checks), checks=checks)


def print_temp_c(program: Program) -> float | None:
    """The first nozzle temperature the program sets (> 0), or None."""
    rows = np.flatnonzero((program.op == SET_TEMP) & (program.aux == NOZZLE) & (program.value > 0))
    return float(program.value[rows[0]]) if len(rows) else None


# --- the items ----------------------------------------------------------------------

def _services(facts: ReadyFacts) -> s.Check:
    dead = [name for name in SERVICES if not facts.alive.get(name)]
    detail = f"all {len(SERVICES)}" if not dead else "down: " + ", ".join(dead)
    return s.Check(name="services alive", ok=not dead, detail=detail)


def _program(facts: ReadyFacts) -> s.Check:
    loaded = bool(facts.program_id)
    return s.Check(name="program planned and loaded", ok=loaded,
                   detail=facts.program_id[:12] if loaded else "no program loaded")


def _collisions(facts: ReadyFacts) -> s.Check:
    name = "program collision-free"
    rep = facts.collisions
    if rep is None:
        why = f"check failed: {facts.collision_error}" if facts.collision_error else "not checked (no program)"
        return s.Check(name=name, ok=False, detail=why)
    hit = rep.first_hit
    if hit is None:
        return s.Check(name=name, ok=True, detail=f"min clearance {rep.min_distance_mm:.1f} mm")
    return s.Check(name=name, ok=False, detail=f"{hit.body_a} <-> {hit.body_b} at line {hit.gcode_line}")


def _pose(facts: ReadyFacts) -> s.Check:
    name = "robot at a known pose"
    if facts.state == Station.INTERRUPTED:
        return s.Check(name=name, ok=False, detail="interrupted: the robot stopped where the station lost it; "
                                                   "recover it (fabric-cli recover) before anything else moves")
    detail = "at home" if facts.at_home else ("within limits" if facts.pose_known else "outside its limits")
    return s.Check(name=name, ok=facts.pose_known, detail=detail)


def _plate(facts: ReadyFacts) -> s.Check:
    if not facts.plate:
        return s.Check(name="plate clear", ok=True, detail="")
    return s.Check(name="plate clear", ok=False, detail=f"holds {facts.plate}: take it off, then fabric-cli "
                                                        f"plate-clear (or go on at a layer: start --layer N)")


def _temperature(facts: ReadyFacts) -> s.Check:
    """Never a blocker: the program sets the nozzle's temperature and waits for it before it extrudes (and the
    twin's interlock refuses to extrude cold), so a cold nozzle, or one a few degrees over after an override, is
    said, not refused."""
    name = "nozzle temperature"
    need_c = facts.print_temp_c
    if need_c is None:
        return s.Check(name=name, ok=True, detail="no print temperature known (no program, or it sets none)")
    detail = f"nozzle {facts.nozzle_c:.0f} C, print needs {need_c:.0f} C"
    if abs(facts.nozzle_c - need_c) <= TEMP_TOLERANCE_C:
        return s.Check(name=name, ok=True, detail=detail)
    return s.Check(name=name, ok=True, detail=detail + ": the program sets it and waits for it before printing")


def _robot(robot: s.RobotStatus) -> s.Check:
    """The robot the station drives: connected, following the twin, no error, no fault (its brakes are open:
    it follows; a robot with its brakes closed or its user stop pressed reports an error or does not follow)."""
    return s.Check(name="robot connected, no error", ok=robot.ok, detail=robot.line())


def _fault(facts: ReadyFacts) -> s.Check:
    fault = facts.state == Station.FAULT
    return s.Check(name="no fault", ok=not fault, detail=facts.reason if fault else "")
