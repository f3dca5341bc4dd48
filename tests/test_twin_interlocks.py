"""Interlocks and refusals: no extrusion below the material's minimum temperature, and a refused command
changes nothing at all (the whole saved state is byte-identical before and after)."""
from __future__ import annotations

from collections.abc import Callable

import pytest

from fabric.motion.program import NOZZLE, Program
from fabric.motion.testprog import square_program
from fabric.motion.thermal import Thermal
from fabric.robot.cell import Cell
from fabric.sim.twin import Twin
from fabric.wire.codec import pack
from fabric.wire.errors import FabricError, StateError, ValidationError


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
def hot(cell: Cell) -> Program:
    return square_program(cell, size_mm=20, layers=3, layer_height_mm=0.5, speed_mm_s=30, nozzle_c=200.0)


def finish(twin: Twin) -> list:
    events: list = []
    for _ in range(100_000):
        if twin.state not in ("printing",) and not twin.moving:
            return events
        events += twin.advance(0.25)
    raise AssertionError("did not settle")


def test_a_cold_nozzle_never_extrudes_and_the_print_pauses_with_the_reason(cell: Cell) -> None:
    tall = square_program(cell, size_mm=20, layers=40, layer_height_mm=0.5, speed_mm_s=30, nozzle_c=200.0)
    twin = Twin(cell)                       # tall enough to outlast the passive cool-down (about 50 s to 170 C)
    twin.load(tall)
    twin.start()
    twin.advance(MID_FIRST_LAYER_S)                        # hot, printing the first layer
    twin.set_overrides(nozzle_c=0.0)                        # heater off (allowed): the nozzle cools down
    events = finish(twin)
    kinds = [e.kind for e in events]
    assert "interlock" in kinds and kinds[-1] == "paused" and twin.state == "paused"
    lock = next(e for e in events if e.kind == "interlock")
    assert lock.data["nozzle_c"] < 170.0 == lock.data["min_c"]
    assert "cold extrusion prevented" in twin.reason
    beads_at_lock = len(twin.beads)
    with pytest.raises(StateError, match="below the material's minimum"):
        twin.resume()                                      # still set cold: refused, nothing changes
    twin.set_overrides(nozzle_c=200.0)
    while twin.temps().nozzle_c < 190.0:
        twin.advance(1.0)
    twin.resume()
    finish(twin)
    assert twin.state == "idle" and len(twin.beads) > beads_at_lock


def test_an_override_below_the_minimum_is_refused_while_printing(cell: Cell, hot: Program) -> None:
    twin = Twin(cell)
    twin.load(hot)
    twin.start()
    twin.advance(10.0)                                     # heating
    before = pack(twin.snapshot())
    with pytest.raises(ValidationError, match="minimum extrusion temperature 170"):
        twin.set_overrides(nozzle_c=120.0, speed_r=0.5)
    assert pack(twin.snapshot()) == before


def test_a_material_without_a_heater_has_no_minimum(cell: Cell) -> None:
    cold = square_program(cell, size_mm=20, layers=2)     # sets no nozzle temperature (clay, concrete)
    twin = Twin(cell)
    twin.load(cold)
    twin.start()
    finish(twin)
    assert twin.state == "idle" and len(twin.beads) == 8


def twin_in(cell: Cell, prog: Program, state: str) -> Twin:
    twin = Twin(cell)
    if state == "idle":
        return twin
    twin.load(prog)
    if state == "ready":
        return twin
    twin.start()
    twin.advance(MID_FIRST_LAYER_S)
    if state == "paused":
        twin.pause()
        twin.advance(2.0)
    elif state == "stopped":
        twin.stop()
        twin.advance(2.0)
    elif state == "interrupted":
        twin.interrupt("station restarted")
    elif state == "fault":
        twin.trip("monitor saw smoke")
    return twin


COMMANDS: dict[str, Callable[[Twin, Program], None]] = {
    "start": lambda t, p: t.start(),
    "start at layer 9": lambda t, p: t.start(from_layer=8),
    "pause": lambda t, p: t.pause(),
    "resume": lambda t, p: t.resume(),
    "stop": lambda t, p: t.stop(),
    "home": lambda t, p: t.go_home(),
    "home, collision": lambda t, p: t.go_home(collision_ok=False),
    "recover": lambda t, p: t.recover(),
    "recover, collision": lambda t, p: t.recover(collision_ok=False),
    "recover at layer 9": lambda t, p: t.recover(from_layer=8),
    "calibrate": lambda t, p: t.calibrate(),
    "load": lambda t, p: t.load(p),
    "speed 11": lambda t, p: t.set_overrides(speed_r=11.0),
    "bed 500 with speed": lambda t, p: t.set_overrides(speed_r=0.5, nozzle_c=210.0, bed_c=500.0),
    "flow nan": lambda t, p: t.set_overrides(flow_r=float("nan")),
}


@pytest.mark.parametrize("state", ["idle", "ready", "printing", "paused", "stopped", "interrupted", "fault"])
def test_every_refused_command_leaves_the_state_unchanged(cell: Cell, hot: Program, state: str) -> None:
    refused = 0
    for name, command in COMMANDS.items():
        twin = twin_in(cell, hot, state)
        before = pack(twin.snapshot())
        try:
            command(twin, hot)
        except FabricError:
            refused += 1
            assert pack(twin.snapshot()) == before, f"{name} refused in {state} but changed the twin"
    assert refused >= 4
