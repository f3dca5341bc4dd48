"""A twin interrupted at any instant (a crashed station restored from its last checkpoint) and recovered
deposits exactly the beads of an uninterrupted run: no bead twice, none missing."""
from __future__ import annotations

import numpy as np
import pytest

from fabric.motion.program import NOZZLE, Program
from fabric.motion.testprog import square_program
from fabric.motion.thermal import Thermal
from fabric.robot.cell import Cell
from fabric.sim.twin import Twin
from fabric.wire.codec import pack, unpack
from fabric.wire.errors import CollisionError, StateError, ValidationError


def _heat_s(nozzle_c: float) -> float:
    """How long the nozzle takes from the room to ``nozzle_c`` (the program's M109), with the twin's heater."""
    th = Thermal()
    th.set_target(NOZZLE, nozzle_c, 0.0)
    return th.wait_s(NOZZLE, 0.0)


MID_FIRST_LAYER_S = _heat_s(200.0) + 2.56        # heated, then printing the first layer


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


@pytest.fixture(scope="module")
def prog(cell: Cell) -> Program:
    return square_program(cell, size_mm=20, layers=3, layer_height_mm=0.5, speed_mm_s=30, nozzle_c=200.0)


def finish(twin: Twin, step_s: float = 0.43) -> list:
    events: list = []
    for _ in range(100_000):
        if twin.state not in ("printing", "paused") and not twin.moving:
            return events
        events += twin.advance(step_s)
    raise AssertionError("the job did not end")


@pytest.fixture(scope="module")
def reference(cell: Cell, prog: Program) -> Twin:
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    finish(twin)
    assert twin.state == "idle" and len(twin.beads) == 12
    return twin


def assert_same_beads(got: Twin, want: Twin) -> None:
    a, b = got.beads.to_arrays(), want.beads.to_arrays()
    assert len(a["row"]) == len(b["row"])
    np.testing.assert_array_equal(a["row"], b["row"])
    np.testing.assert_allclose(a["start_mm"], b["start_mm"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(a["end_mm"], b["end_mm"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(a["volume_mm3"], b["volume_mm3"], rtol=1e-9, atol=0)


def crash_and_recover(cell: Cell, prog: Program, t_checkpoint: float, t_crash: float,
                      pause_at: float | None = None) -> Twin:
    """Run to ``t_checkpoint`` (pausing at ``pause_at``), save, restore in a fresh twin, advance to the
    crash instant, interrupt, recover and finish."""
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    if pause_at is not None:
        twin.advance(pause_at)
        twin.pause()
        twin.advance(t_checkpoint - pause_at)
    else:
        twin.advance(t_checkpoint)
    snap = unpack(pack(twin.snapshot()))
    again = Twin.from_snapshot(cell, snap, prog)
    again.advance(t_crash - t_checkpoint)
    again.interrupt("station restarted")
    assert again.state == "interrupted"
    assert not again.extrusion().on
    at = again.pose().xyz_mm.copy()
    events = again.advance(5.0)
    np.testing.assert_allclose(again.pose().xyz_mm, at, atol=1e-9)     # it does not move by itself
    assert "interrupted" in [e.kind for e in again.s.pending + events] or again.state == "interrupted"
    again.recover()
    events = finish(again)
    kinds = [e.kind for e in events]
    assert kinds[0] == "recovered" and kinds[-1] == "finished"
    return again


@pytest.mark.parametrize("seed", range(20))
def test_random_crash_instants_recover_to_identical_beads(cell: Cell, prog: Program, reference: Twin,
                                                          seed: int) -> None:
    rng = np.random.default_rng(seed)
    total = reference.time_info().total_s
    first_bead = _heat_s(200.0) + 0.06                  # the heat-up takes most of the job's time
    t_crash = float(rng.uniform(first_bead if seed < 15 else 1.0, total - 0.3))
    t_checkpoint = float(max(0.0, t_crash - rng.uniform(0.0, 3.0)))
    twin = crash_and_recover(cell, prog, t_checkpoint, t_crash)
    assert twin.t_sim_s > t_crash
    assert_same_beads(twin, reference)
    assert twin.extrusion().extruded_mm3 == pytest.approx(reference.extrusion().extruded_mm3, rel=1e-9)


@pytest.mark.parametrize("t_crash", [MID_FIRST_LAYER_S + 0.004, MID_FIRST_LAYER_S + 0.05,     # stopping, lifting,
                                     MID_FIRST_LAYER_S + 2.0])                                 # paused
def test_crash_during_a_pause_recovers_to_identical_beads(cell: Cell, prog: Program, reference: Twin,
                                                          t_crash: float) -> None:
    twin = crash_and_recover(cell, prog, t_checkpoint=MID_FIRST_LAYER_S + 0.002, t_crash=t_crash,
                             pause_at=MID_FIRST_LAYER_S)
    assert_same_beads(twin, reference)


def test_recover_is_refused_unless_interrupted_and_checked(cell: Cell, prog: Program) -> None:
    twin = Twin(cell)
    twin.load(prog)
    with pytest.raises(StateError):
        twin.recover()
    twin.start()
    twin.advance(MID_FIRST_LAYER_S)
    twin.interrupt("station restarted")
    rest, spot = twin.recovery_move()
    np.testing.assert_allclose(rest, spot, atol=1e-12)               # it stopped dead on the path
    with pytest.raises(CollisionError):
        twin.recover(collision_ok=False)
    assert twin.state == "interrupted"                               # a refused recover changes nothing
    with pytest.raises(StateError):
        twin.start()
    twin.recover()
    assert twin.state == "printing" and twin.recovery_move() is None


def test_interrupt_of_an_idle_twin_changes_nothing(cell: Cell) -> None:
    twin = Twin(cell)
    before = twin.pose().q_rad.copy()
    twin.interrupt("station restarted")
    assert twin.state == "idle"
    np.testing.assert_array_equal(twin.pose().q_rad, before)


def test_restart_at_a_layer_after_a_stop_heats_and_prints_the_rest(cell: Cell, prog: Program,
                                                                   reference: Twin) -> None:
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    while twin.extrusion().layer < 1:
        twin.advance(0.25)
    twin.stop()
    finish(twin)
    assert twin.state == "stopped" and twin.temps().nozzle_target_c == 0.0
    stopped_beads = len(twin.beads)
    with pytest.raises(ValidationError, match="no layer 9"):
        twin.start(from_layer=8)
    assert twin.state == "stopped"                                     # refused: nothing changed
    twin.start(from_layer=2)
    events = finish(twin)
    kinds = [e.kind for e in events]
    assert kinds[:2] == ["started", "temp_reached"] and "at_layer" in kinds and kinds[-1] == "finished"
    layer2 = reference.beads.to_arrays()
    want = layer2["end_mm"][layer2["layer"] == 2]
    got = twin.beads.to_arrays()
    np.testing.assert_allclose(got["end_mm"][stopped_beads:], want, atol=1e-9)   # layer 3 printed as planned


def test_recover_at_the_layer_it_was_cut_in_goes_on_where_it_stopped(cell: Cell, prog: Program,
                                                                      reference: Twin) -> None:
    """Interrupted inside layer 2, recovered at layer 2: the row cut short is a partial bead and the print goes on
    from where it stopped (the restart's move above that spot, then down), not from the layer's first row
    through what it laid: the same volume as an uninterrupted print, layer 2 once."""
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    twin.advance(MID_FIRST_LAYER_S + 2.5)                               # inside layer 2
    twin.interrupt("station restarted")
    at = twin.recovery_move(from_layer=1)
    at_row = twin.resume_row
    assert at is not None and not np.allclose(at[0], at[1])
    partial = twin.beads.to_arrays()["row"]
    twin.recover(from_layer=1)
    finish(twin)
    assert (twin.state, twin.reason) == ("idle", "finished")
    rows = twin.beads.to_arrays()["row"]
    assert (rows == at_row).sum() == 2 and at_row not in partial         # the cut row: a partial bead, then the rest
    assert twin.beads.total_volume_mm3 == pytest.approx(reference.beads.total_volume_mm3, rel=1e-3)
