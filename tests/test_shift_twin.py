"""What the twin says during an operator's shift (issue 24): reasons that end with what they describe, a layer's
Z as printed, overrides that end with their job, progress as the place in the program, heaters as a real hotend."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from fabric.motion.program import Program
from fabric.motion.testprog import square_program
from fabric.planning import plan_gcode
from fabric.robot.cell import Cell
from fabric.services.station_messages import StationMessages
from fabric.sim.twin import Twin
from fabric.store.journal import StationMeta

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


@pytest.fixture(scope="module")
def prog(cell: Cell) -> Program:
    return square_program(cell, size_mm=20, layers=3, layer_height_mm=0.5, speed_mm_s=30)


def run(twin: Twin, step_s: float = 0.5) -> list:
    events: list = []
    for _ in range(100_000):
        if twin.state not in ("printing", "paused") and not twin.moving:
            return events
        events += twin.advance(step_s)
    raise AssertionError("the job did not end")


def test_home_says_at_home_once_there(cell: Cell) -> None:
    twin = Twin(cell)
    twin.go_home()
    assert twin.reason == "homing"
    run(twin)
    assert twin.state == "idle" and twin.reason == "at home"     # was "homing" for ever


def test_recovering_and_resuming_end_when_the_move_back_does(cell: Cell, prog: Program) -> None:
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    twin.advance(5.0)
    twin.pause()
    twin.advance(2.0)
    twin.resume()
    assert twin.reason == "resuming"
    events = twin.advance(3.0)
    assert "resumed" in [e.kind for e in events] and twin.reason == "resumed"
    twin.interrupt("the station stopped")
    twin.recover()
    assert twin.reason == "recovering"
    events = twin.advance(3.0)
    assert "recovered" in [e.kind for e in events] and twin.state == "printing"
    assert twin.reason == "recovered"                              # was "recovering" for the rest of the print


def test_a_layer_event_says_the_z_the_layer_is_printed_at(cell: Cell) -> None:
    gcode = "; filament_diameter = 1.75\nG21\nG90\nM83\n"
    for k in range(4):                          # as slicers write it: Z first, then the travel, then the perimeter
        z = 0.3 * (k + 1)
        gcode += (f";LAYER_CHANGE\n;Z:{z:.2f}\nG1 Z{z:.2f} F600\nG1 X100 Y100 F3000\nG1 X120 Y100 E1 F1200\n"
                  "G1 X120 Y120 E1\nG1 X100 Y120 E1\n")
    twin = Twin(cell)
    twin.load(plan_gcode(gcode, cell).program)
    twin.start()
    layers = [e for e in run(twin, 5.0) if e.kind == "layer"]
    assert [e.layer for e in layers] == [0, 1, 2, 3]
    assert [e.data["z_mm"] for e in layers] == pytest.approx([0.3, 0.6, 0.9, 1.2])


def test_speed_and_flow_overrides_end_with_their_job(cell: Cell, prog: Program) -> None:
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    twin.advance(2.0)
    twin.set_overrides(speed_r=1.5, flow_r=1.1)
    run(twin)
    assert (twin.speed_r, twin.flow_r) == (1.5, 1.1)                # still in force: the job's record says so
    twin.load(prog)                                                # the next job
    assert (twin.speed_r, twin.flow_r) == (1.0, 1.0)
    twin.start()
    run(twin)
    assert twin.extrusion().extruded_mm3 == pytest.approx(prog.deposited_volume_mm3(), rel=1e-9)


def test_progress_is_the_place_in_the_program_whatever_the_flow(cell: Cell) -> None:
    """Issue 24: with flow x1.1 the deposited volume reached the planned one layers before the end (100 %)."""
    prog = square_program(cell, size_mm=20, layers=10, layer_height_mm=0.5, speed_mm_s=30)
    twin = Twin(cell)
    meta = StationMeta(planned_mm3=prog.deposited_volume_mm3(), layers_total=10)
    msgs = StationMessages(twin, meta)
    twin.load(prog)
    twin.start()
    twin.set_overrides(flow_r=1.25)
    seen = []
    while twin.state == "printing":
        twin.advance(1.0)
        st = msgs.state()
        if st.state == "printing":
            seen.append((st.layer, st.progress_r, st.deposited_mm3 / st.planned_mm3))
    before_last = [(p, d) for layer, p, d in seen if layer < 9]
    assert max(d for _, d in before_last) >= 1.0                   # the planned volume is out before the last layer
    assert max(p for p, _ in before_last) <= 0.9 + 1e-9              # yet the place in the program is 9/10 at most
    assert all(b >= a for (_, a, _), (_, b, _) in itertools.pairwise(seen))
    assert msgs.state().progress_r == 1.0 and twin.reason == "finished"
    assert np.isclose(seen[len(seen) // 2][1], 0.5, atol=0.15)
