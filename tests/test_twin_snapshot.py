"""The twin's state saved mid-print and restored in a fresh twin finishes exactly as an uninterrupted run."""
from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from fabric.motion.program import NOZZLE, Program
from fabric.motion.testprog import square_program
from fabric.motion.thermal import Thermal
from fabric.robot.cell import Cell
from fabric.sim.twin import Twin
from fabric.wire.codec import pack, unpack
from fabric.wire.errors import ValidationError


def _heat_s(nozzle_c: float) -> float:
    """How long the nozzle takes from the room to ``nozzle_c`` (the program's M109), with the twin's heater."""
    th = Thermal()
    th.set_target(NOZZLE, nozzle_c, 0.0)
    return th.wait_s(NOZZLE, 0.0)


MID_FIRST_LAYER_S = _heat_s(200.0) + 2.56        # heated, then printing the first layer

Script = list[tuple[float, Callable[[Twin], None] | None]]


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


@pytest.fixture(scope="module")
def prog(cell: Cell) -> Program:
    return square_program(cell, size_mm=20, layers=3, layer_height_mm=0.5, speed_mm_s=30, nozzle_c=200.0)


def play(twin: Twin, script: Script, events: list) -> None:
    """Advance by each step, then apply its command (if any)."""
    for dt, command in script:
        events += twin.advance(dt)
        if command is not None:
            command(twin)


def finish(twin: Twin, events: list, step_s: float = 0.37) -> None:
    for _ in range(100_000):
        if twin.state not in ("printing", "paused") and not twin.moving:
            return
        events += twin.advance(step_s)
    raise AssertionError("the job did not end")


def beads(twin: Twin) -> dict[str, np.ndarray]:
    return twin.beads.to_arrays()


def pause(t: Twin) -> None:
    t.pause()


def resume(t: Twin) -> None:
    t.resume()


def slower(t: Twin) -> None:
    t.set_overrides(speed_r=0.6, flow_r=1.1)


def hotter(t: Twin) -> None:
    t.set_overrides(nozzle_c=215.0)


def stop(t: Twin) -> None:
    t.stop()


# (name, commands before the save, commands after it); times are simulated seconds
SCENARIOS: dict[str, tuple[Script, Script]] = {
    "heating": ([(8.0, None)], []),
    "heating, set point changed": ([(8.0, hotter), (3.0, None)], []),
    "mid-layer": ([(MID_FIRST_LAYER_S, None)], []),
    "second layer, paused there": ([(MID_FIRST_LAYER_S + 2.5, None)], [(0.3, pause), (2.0, resume)]),
    "right after a pause": ([(MID_FIRST_LAYER_S, pause), (0.004, None)], [(2.0, resume)]),
    "lifting": ([(MID_FIRST_LAYER_S, pause), (0.05, None)], [(1.0, resume)]),
    "paused": ([(MID_FIRST_LAYER_S, pause), (3.0, None)], [(1.0, resume)]),
    "going back down": ([(MID_FIRST_LAYER_S, pause), (3.0, resume), (0.05, None)], []),
    "paused twice": ([(MID_FIRST_LAYER_S, pause), (3.0, resume), (0.05, pause), (0.01, None)], [(2.0, resume)]),
    "after an override": ([(MID_FIRST_LAYER_S, slower), (0.001, None)], []),
    "stopping": ([(MID_FIRST_LAYER_S, stop), (0.002, None)], []),
}


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_restored_twin_finishes_like_an_uninterrupted_one(cell: Cell, prog: Program, name: str) -> None:
    before, after = SCENARIOS[name]
    ref = Twin(cell)
    ref.load(prog)
    ref.start()
    ref_events: list = []
    play(ref, before, ref_events)
    cut = len(ref_events)
    snap = unpack(pack(ref.snapshot()))          # through the fabric's msgpack codec, as a checkpoint would go
    play(ref, after, ref_events)
    finish(ref, ref_events)

    twin = Twin.from_snapshot(cell, snap, prog)
    assert twin.state == unpack(pack(snap))["state"]["state"]
    events: list = []
    play(twin, after, events)
    finish(twin, events)

    assert twin.state == ref.state and twin.t_sim_s == ref.t_sim_s
    assert [(e.seq, e.kind, e.t_sim_s, e.row) for e in events] == \
        [(e.seq, e.kind, e.t_sim_s, e.row) for e in ref_events[cut:]]
    got, want = beads(twin), beads(ref)
    assert len(got["row"]) == len(want["row"]) > 0
    for k in want:
        np.testing.assert_array_equal(got[k], want[k], err_msg=k)
    assert twin.extrusion().extruded_mm3 == ref.extrusion().extruded_mm3
    assert twin.temps() == ref.temps() and twin.time_info() == ref.time_info()


def test_snapshot_of_a_restored_twin_is_the_same(cell: Cell, prog: Program) -> None:
    twin = Twin(cell, retract_mm=0.8)
    twin.load(prog)
    twin.start()
    twin.advance(MID_FIRST_LAYER_S)
    twin.pause()
    twin.advance(0.01)
    first = pack(twin.snapshot())
    again = Twin.from_snapshot(cell, unpack(first), prog)
    assert again.config.retract_mm == 0.8
    assert pack(again.snapshot()) == first


def test_idle_twin_round_trips_its_work_object_and_probe_noise(cell: Cell) -> None:
    twin = Twin(cell)
    twin.calibrate()
    copy = Twin.from_snapshot(cell, unpack(pack(twin.snapshot())), None)
    np.testing.assert_array_equal(copy.work_object_T, twin.work_object_T)
    a, b = twin.calibrate(), copy.calibrate()                    # same random probe noise from here on
    np.testing.assert_array_equal(a.work_object_T, b.work_object_T)


def test_restore_refuses_another_program_or_version(cell: Cell, prog: Program) -> None:
    twin = Twin(cell)
    twin.load(prog)
    snap = twin.snapshot()
    other = square_program(cell, size_mm=10, layers=2)
    with pytest.raises(ValidationError, match="rows"):
        Twin.from_snapshot(cell, snap, other)
    with pytest.raises(ValidationError, match="rows"):
        Twin.from_snapshot(cell, snap, None)
    snap["state"]["version"] = 99
    with pytest.raises(ValidationError, match="version"):
        Twin.from_snapshot(cell, snap, prog)
    snap = twin.snapshot()
    snap["config"]["warp_factor"] = 9
    with pytest.raises(ValidationError, match="warp_factor"):
        Twin.from_snapshot(cell, snap, prog)


def test_snapshot_without_beads_takes_them_apart(cell: Cell, prog: Program) -> None:
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    twin.advance(95.0)
    snap = twin.snapshot(with_beads=False)
    assert snap["state"]["beads"] is None and snap["state"]["bead_count"] == len(twin.beads) > 0
    again = Twin.from_snapshot(cell, snap, prog, beads=twin.beads.to_arrays())
    assert len(again.beads) == len(twin.beads)
    short = {k: v[:-1] for k, v in twin.beads.to_arrays().items()}
    with pytest.raises(ValidationError, match="beads"):
        Twin.from_snapshot(cell, snap, prog, beads=short)
    with pytest.raises(ValidationError, match="beads"):
        Twin.from_snapshot(cell, snap, prog)
