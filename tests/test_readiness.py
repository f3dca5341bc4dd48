"""The ready checklist as a pure function: each item passes or fails with its explanation."""
from __future__ import annotations

from dataclasses import replace

from fabric import schemas as s
from fabric.motion.program import BED, NOZZLE, SET_TEMP, Program
from fabric.services.readiness import ReadyFacts, print_temp_c, ready_report
from fabric.wire.keys import SERVICES

ALL_ALIVE = {name: True for name in SERVICES}
CLEAR = s.CollisionReport(collision_free=True, checked_configs=100, min_distance_mm=12.34)
HIT = s.CollisionReport(collision_free=False, checked_configs=40, min_distance_mm=0.0,
                        first_hit=s.CollisionHit(body_a="link_4", body_b="plate", gcode_line=17, row=9))
READY = ReadyFacts(alive=ALL_ALIVE, program_id="0123456789abcdef", collisions=CLEAR, collision_error="",
                   pose_known=True, at_home=True, nozzle_c=212.0, print_temp_c=210.0, state="ready")


def check(facts: ReadyFacts, name: str) -> s.Check:
    report = ready_report(facts)
    (item,) = [c for c in report.checks if c.name == name]
    assert report.ready == all(c.ok for c in report.checks)
    return item


def test_everything_in_order_is_ready() -> None:
    report = ready_report(READY)
    assert report.ready
    assert [c.name for c in report.checks] == ["services alive", "program planned and loaded",
                                               "program collision-free", "robot at a known pose",
                                               "plate clear", "nozzle temperature", "no fault"]
    assert [c.detail for c in report.checks] == [f"all {len(SERVICES)}", "0123456789ab", "min clearance 12.3 mm",
                                                 "at home", "", "nozzle 212 C, print needs 210 C", ""]


def test_dead_services_are_named() -> None:
    item = check(replace(READY, alive={**ALL_ALIVE, "planner": False, "collision": False}), "services alive")
    assert not item.ok and item.detail == "down: planner, collision"
    item = check(replace(READY, alive={}), "services alive")
    assert not item.ok and item.detail == "down: " + ", ".join(SERVICES)


def test_no_program_fails_loading_and_the_sweep() -> None:
    facts = replace(READY, program_id="", collisions=None)
    assert not ready_report(facts).ready
    item = check(facts, "program planned and loaded")
    assert not item.ok and item.detail == "no program loaded"
    item = check(facts, "program collision-free")
    assert not item.ok and item.detail == "not checked (no program)"


def test_collisions_name_the_bodies_and_the_line() -> None:
    item = check(replace(READY, collisions=HIT), "program collision-free")
    assert not item.ok and item.detail == "link_4 <-> plate at line 17"
    item = check(replace(READY, collisions=None, collision_error="no reply from collision/check"),
                 "program collision-free")
    assert not item.ok and item.detail == "check failed: no reply from collision/check"


def test_pose_outside_limits_fails_and_away_from_home_passes() -> None:
    item = check(replace(READY, at_home=False), "robot at a known pose")
    assert item.ok and item.detail == "within limits"
    item = check(replace(READY, at_home=False, pose_known=False), "robot at a known pose")
    assert not item.ok and item.detail == "outside its limits"


def test_an_interrupted_print_fails_the_pose_until_recovered() -> None:
    item = check(replace(READY, state="interrupted", at_home=False), "robot at a known pose")
    assert not item.ok and "recover" in item.detail


def test_the_nozzle_temperature_is_said_never_a_blocker() -> None:
    """Issue 24: an idle nozzle the program heats anyway, or one 8 C over its set point after an override, made
    ready say NOT READY."""
    item = check(replace(READY, nozzle_c=25.0), "nozzle temperature")
    assert item.ok and ready_report(replace(READY, nozzle_c=25.0)).ready
    assert item.detail == "nozzle 25 C, print needs 210 C: the program sets it and waits for it before printing"
    assert check(replace(READY, nozzle_c=218.0), "nozzle temperature").ok
    assert check(replace(READY, nozzle_c=205.0), "nozzle temperature").detail == "nozzle 205 C, print needs 210 C"
    item = check(replace(READY, print_temp_c=None), "nozzle temperature")
    assert item.ok and "no print temperature known" in item.detail


def test_a_fault_gives_its_reason() -> None:
    item = check(replace(READY, state="fault", reason="monitor: nozzle thermal runaway"), "no fault")
    assert not item.ok and item.detail == "monitor: nozzle thermal runaway"


def test_print_temperature_is_the_first_nozzle_setting() -> None:
    p = Program.empty(4)
    p.op[:] = SET_TEMP
    p.aux[:] = [BED, NOZZLE, NOZZLE, NOZZLE]
    p.value[:] = [60.0, 0.0, 215.0, 200.0]
    assert print_temp_c(p) == 215.0
    p.aux[:] = BED
    assert print_temp_c(p) is None
