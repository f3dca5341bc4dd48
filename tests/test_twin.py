"""The twin's state machine: exact timing under any stepping, pause/resume, stop, overrides, heat, faults."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from fabric.motion.program import BED, Program
from fabric.motion.testprog import square_program
from fabric.motion.thermal import Thermal
from fabric.robot.cell import Cell
from fabric.sim.twin import Twin
from fabric.wire.errors import CollisionError, StateError, UnreachableError, ValidationError


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


@pytest.fixture(scope="module")
def prog(cell: Cell) -> Program:
    return square_program(cell, size_mm=20, layers=3, layer_height_mm=0.5, speed_mm_s=30)


def run(twin: Twin, step_s: float, max_steps: int = 200_000) -> list:
    """Advance in steps of ``step_s`` until the job and any motion are over; all events."""
    events: list = []
    for _ in range(max_steps):
        if twin.state not in ("printing", "paused") and not twin.moving:
            return events
        events += twin.advance(step_s)
    raise AssertionError("the job did not end")


def kinds(events: list) -> list[str]:
    return [e.kind for e in events]


def test_same_total_and_volume_for_fine_and_huge_steps(cell: Cell, prog: Program) -> None:
    results = []
    for step in (0.001, 1e6):
        twin = Twin(cell)
        est = twin.load(prog).estimate_s
        assert twin.time_info().estimate_s == est and twin.state == "ready"
        twin.start()
        events = run(twin, step)
        fin = [e for e in events if e.kind == "finished"]
        assert len(fin) == 1 and twin.state == "idle"
        total = twin.time_info().total_s
        assert total == pytest.approx(est, rel=1e-9)           # the estimate is the executed schedule
        assert fin[0].t_sim_s == pytest.approx(est, rel=1e-9)
        results.append((total, twin.extrusion().extruded_mm3, twin.beads.total_volume_mm3, len(twin.beads)))
        seqs = [e.seq for e in events]
        assert seqs == sorted(seqs) and all(b.t_sim_s >= a.t_sim_s for a, b in itertools.pairwise(events))
    (t1, v1, b1, n1), (t2, v2, b2, n2) = results
    assert t1 == pytest.approx(t2, rel=1e-12)
    assert v1 == pytest.approx(v2, rel=1e-12) and v1 == pytest.approx(prog.deposited_volume_mm3(), rel=1e-9)
    assert b1 == pytest.approx(b2, rel=1e-12) and n1 == n2 == 12   # 3 layers x 4 sides


def test_pause_resume_mid_layer_gives_identical_beads(cell: Cell, prog: Program) -> None:
    ref = Twin(cell)
    ref.load(prog)
    ref.start()
    run(ref, 1e6)

    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    twin.advance(5.0)                                          # mid-way through the second layer
    assert twin.state == "printing" and twin.extrusion().on
    before = twin.extrusion().extruded_mm3
    twin.pause()
    assert twin.state == "paused"
    events = twin.advance(1.0)
    assert kinds(events) == ["paused"] and not twin.extrusion().on
    stopped_at = events[0].data["xyz_mm"]
    lifted = twin.pose()
    assert lifted.xyz_mm[2] == pytest.approx(stopped_at[2] + twin.config.lift_mm, abs=1e-6)
    assert not twin.extrusion().on
    assert twin.extrusion().filament_mm == pytest.approx(twin.extrusion().extruded_mm3 / (np.pi * 1.75 ** 2 / 4)
                                                         - twin.config.retract_mm)
    vol_paused = twin.extrusion().extruded_mm3
    assert vol_paused > before                                 # the controlled stop still extrudes
    twin.advance(30.0)                                         # a long pause: nothing moves, nothing extrudes
    assert twin.extrusion().extruded_mm3 == vol_paused
    np.testing.assert_allclose(twin.pose().base_xyz_mm, lifted.base_xyz_mm)
    twin.resume()
    events = run(twin, 0.01)
    assert kinds(events)[0] == "resumed"
    assert len(twin.beads) == len(ref.beads)
    np.testing.assert_allclose(twin.beads.start_mm, ref.beads.start_mm, atol=1e-9, rtol=0)
    np.testing.assert_allclose(twin.beads.end_mm, ref.beads.end_mm, atol=1e-9, rtol=0)
    np.testing.assert_allclose(twin.beads.volume_mm3, ref.beads.volume_mm3, atol=1e-9, rtol=0)
    np.testing.assert_array_equal(twin.beads.row, ref.beads.row)
    assert twin.extrusion().extruded_mm3 == pytest.approx(ref.extrusion().extruded_mm3, rel=1e-12)
    info = twin.time_info()
    assert info.total_s > ref.time_info().total_s + 30.0      # the pause shows in the elapsed time


def test_wrong_transitions_raise_state_error(cell: Cell, prog: Program) -> None:
    twin = Twin(cell)
    for command in (twin.pause, twin.resume, twin.start, twin.stop):
        with pytest.raises(StateError) as e:
            command()
        assert e.value.details["state"] == "idle" and e.value.details["command"]
    twin.load(prog)
    twin.start()
    for command in (twin.start, twin.resume, twin.calibrate, twin.go_home, lambda: twin.load(prog)):
        with pytest.raises(StateError) as e:
            command()
        assert e.value.details["state"] == "printing"
    twin.pause()
    with pytest.raises(StateError):
        twin.pause()
    twin.stop()
    with pytest.raises(StateError) as e:
        twin.resume()
    assert e.value.details["state"] == "stopped"


def test_stop_keeps_partial_bead_and_goes_safe(cell: Cell) -> None:
    prog = square_program(cell, nozzle_c=200.0)
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    while not twin.extrusion().on:                              # heat up, approach, start printing
        twin.advance(0.05)
    twin.advance(2.5)
    n_done = len(twin.beads)
    twin.stop()
    assert twin.state == "stopped" and twin.temps().nozzle_target_c == 0.0
    events = twin.advance(2.0)
    assert kinds(events) == ["stopped"] and not twin.extrusion().on
    assert len(twin.beads) == n_done + 1                       # the row in progress, partially
    part = twin.beads
    assert np.linalg.norm(part.end_mm[-1] - part.start_mm[-1]) < 20.0
    assert part.total_volume_mm3 == pytest.approx(twin.extrusion().extruded_mm3, rel=1e-12)
    assert twin.pose().base_xyz_mm[2] > cell.wobj_T()[2, 3] + twin.config.lift_mm
    twin.go_home()
    events = run(twin, 0.5)
    assert kinds(events) == ["home"]
    np.testing.assert_allclose(twin.pose().q_rad, cell.home_q_rad, atol=1e-12)


def test_speed_and_flow_overrides_retime_the_rest(cell: Cell, prog: Program) -> None:
    ref = Twin(cell)
    ref.load(prog)
    ref.start()
    run(ref, 1e6)
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    twin.advance(3.0)
    twin.set_overrides(speed_r=0.5)
    assert twin.time_info().total_s > ref.time_info().total_s + 2.0
    run(twin, 0.02)
    assert twin.time_info().total_s > ref.time_info().total_s + 2.0
    np.testing.assert_allclose(twin.beads.end_mm, ref.beads.end_mm, atol=1e-9)
    assert twin.extrusion().extruded_mm3 == pytest.approx(ref.extrusion().extruded_mm3, rel=1e-9)
    more = Twin(cell)
    more.load(prog)
    more.start()
    more.set_overrides(flow_r=1.1)
    run(more, 1e6)
    assert more.extrusion().extruded_mm3 == pytest.approx(1.1 * ref.extrusion().extruded_mm3, rel=1e-9)
    with pytest.raises(ValidationError):
        more.set_overrides(speed_r=0.0)


def test_heat_up_is_waited_exactly_and_reported(cell: Cell) -> None:
    prog = square_program(cell, nozzle_c=210.0, bed_c=60.0)
    twin = Twin(cell)
    est = twin.load(prog).estimate_s
    twin.start()
    events = run(twin, 0.25)
    reached = [e for e in events if e.kind == "temp_reached"]
    assert [e.data["heater"] for e in reached] == ["bed", "nozzle"]
    bed = Thermal().params[BED]
    heat = Thermal()
    heat.set_target(BED, 60.0, 0.0)
    assert reached[0].t_sim_s == pytest.approx(heat.wait_s(BED, 0.0), rel=1e-12)
    assert reached[0].data["temp_c"] == pytest.approx(60.0 - bed.tol_c)
    assert twin.time_info().total_s == pytest.approx(est, rel=1e-9)
    assert twin.temps().nozzle_c == pytest.approx(210.0, abs=2.0)


def test_pause_during_heat_up_and_override_of_set_point(cell: Cell) -> None:
    prog = square_program(cell, nozzle_c=210.0)
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    twin.advance(10.0)                                         # heating
    twin.pause()
    ev = twin.advance(1.0)
    assert kinds(ev) == ["paused"]
    twin.resume()
    twin.set_overrides(nozzle_c=180.0)
    events = run(twin, 0.5)
    reached = [e for e in events if e.kind == "temp_reached"]
    assert reached and reached[0].data["target_c"] == 180.0
    assert kinds(events)[-1] == "finished" and len(twin.beads) == 12


def test_load_validation_and_faults(cell: Cell, prog: Program) -> None:
    twin = Twin(cell)
    bad = prog.slice(0)
    bad.q_rad = bad.q_rad.copy()
    bad.q_rad[3, 4] = np.radians(150.0)
    bad.gcode_line = bad.gcode_line.copy()
    with pytest.raises(UnreachableError) as e:
        twin.load(bad)
    assert e.value.details["row"] == 3 and e.value.details["joint"] == 4
    assert twin.state == "idle"
    with pytest.raises(CollisionError):
        twin.go_home(collision_ok=False)
    twin.load(prog)
    twin.start()
    twin.advance(4.0)
    twin.trip("monitor: nozzle thermal runaway")
    events = twin.advance(0.1)
    assert kinds(events) == ["fault"] and twin.state == "fault" and not twin.extrusion().on
    assert "runaway" in twin.reason and twin.temps().nozzle_target_c == 0.0
    here = twin.pose().base_xyz_mm
    twin.advance(5.0)
    np.testing.assert_allclose(twin.pose().base_xyz_mm, here)  # instant stop: nothing moves
    twin.go_home()
    assert kinds(run(twin, 1.0)) == ["home"]


def test_time_info_predicts_the_executed_total(cell: Cell, prog: Program) -> None:
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    twin.advance(4.0)
    twin.set_overrides(speed_r=1.6)
    predicted = twin.time_info().total_s                      # re-timed remainder, before it runs
    twin.advance(1.0)
    twin.pause()
    twin.advance(3.0)
    assert twin.state == "paused" and not twin.moving
    paused_pred = twin.time_info().total_s                    # if resumed now
    assert paused_pred > predicted
    twin.resume()
    run(twin, 0.05)
    assert twin.time_info().total_s == pytest.approx(paused_pred, rel=1e-9)


def test_pause_in_joint_move_and_during_resume(cell: Cell, prog: Program) -> None:
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    twin.advance(0.3)                                          # inside the approach MoveJ
    assert twin.pose().q_rad[0] != pytest.approx(prog.q_rad[0][0])
    twin.pause()
    events = twin.advance(5.0)
    assert kinds(events) == ["paused"]                        # the joint move is finished first
    assert events[0].data["resume_row"] == 1
    np.testing.assert_allclose(twin.pose().xyz_mm, prog.xyz_mm[0] + [0, 0, twin.config.lift_mm], atol=1e-6)
    twin.resume()
    twin.advance(0.01)                                         # going back down
    twin.pause()                                               # ... and pause again: that resume never completes
    events = twin.advance(2.0)
    assert kinds(events) == ["paused"] and twin.state == "paused"
    twin.resume()
    events = run(twin, 0.1)
    assert kinds(events).count("resumed") == 1 and kinds(events)[-1] == "finished"
    assert len(twin.beads) == 12


def test_stop_while_paused_records_the_partial_row(cell: Cell, prog: Program) -> None:
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    twin.advance(3.0)
    twin.pause()
    twin.advance(2.0)
    n = len(twin.beads)
    vol = twin.extrusion().extruded_mm3
    twin.stop()
    events = twin.advance(0.0)
    assert kinds(events) == ["stopped"] and twin.state == "stopped" and not twin.moving
    assert len(twin.beads) == n + 1 and twin.beads.total_volume_mm3 == pytest.approx(vol, rel=1e-12)
    assert twin.time_info().remaining_s == 0.0
