"""The post-processors' row walker: typed events and the one extruder state machine."""
from __future__ import annotations

import numpy as np
import pytest

from fabric.motion.program import BED, MOVEJ, MOVEL, NOZZLE, PRINT, RETRACT, SET_TEMP, WAIT, WAIT_TEMP, Program
from fabric.planning.post.walk import (
    BED_HEATER,
    NOZZLE_HEATER,
    Block,
    ExtruderOff,
    ExtruderOn,
    ExtruderRate,
    JointMove,
    LayerStart,
    LinearMove,
    LinearRun,
    Retract,
    RowWalker,
    SetTemp,
    Wait,
    WaitTemp,
)
from fabric.wire.errors import ValidationError


def _program(rows: list[tuple]) -> Program:
    """Rows of (op, flow_mm3_mm, speed_mm_s, value, aux, layer); all print section."""
    p = Program.empty(len(rows))
    for i, (op, flow, speed, value, aux, layer) in enumerate(rows):
        p.op[i], p.flow_mm3_mm[i], p.speed_mm_s[i] = op, flow, speed
        p.value[i], p.aux[i], p.layer[i] = value, aux, layer
    p.section[:] = PRINT
    return p


def _events(p: Program, block_rows: int = 1000) -> list:
    return [ev for ev in RowWalker(p, block_rows).walk() if not isinstance(ev, Block)]


def test_extruder_on_rate_change_off_ride_on_linear_moves() -> None:
    p = _program([(MOVEJ, 0, 0, 0, 0, 0), (MOVEL, 0.1, 10, 0, 0, 0), (MOVEL, 0.1, 10, 0, 0, 0),
                  (MOVEL, 0.1, 20, 0, 0, 0), (MOVEL, 0.0, 50, 0, 0, 0), (MOVEL, 0.0, 50, 0, 0, 0)])
    assert _events(p) == [LayerStart(0), JointMove(0), LinearMove(1, ExtruderOn(1.0)), LinearMove(2, None),
                          LinearMove(3, ExtruderRate(2.0)), LinearMove(4, ExtruderOff()), LinearMove(5, None)]


@pytest.mark.parametrize("op, value, aux, events", [
    (WAIT, 1.5, 0, [ExtruderOff(), Wait(2, 1.5)]),
    (RETRACT, -0.8, 0, [ExtruderOff(), Retract(2, -0.8)]),
    (WAIT_TEMP, 60.0, BED, [SetTemp(2, BED_HEATER, 60.0), ExtruderOff(), WaitTemp(2, BED_HEATER, 60.0)]),
    (SET_TEMP, 210.0, NOZZLE, [SetTemp(2, NOZZLE_HEATER, 210.0)]),
    (MOVEJ, 0.0, 0, [ExtruderOff(), JointMove(2)]),
])
def test_robot_standing_still_switches_the_extruder_off_first(op, value, aux, events) -> None:
    # extruding, then a row that stops the path: the extruder goes off before it (a heater set point does not stop)
    p = _program([(MOVEL, 0.1, 10, 0, 0, 0), (MOVEL, 0.1, 10, 0, 0, 0), (op, 0, 0, value, aux, 0),
                  (MOVEL, 0.1, 10, 0, 0, 0)])
    evs = _events(p)
    assert evs[:3] == [LayerStart(0), LinearMove(0, ExtruderOn(1.0)), LinearMove(1, None)]
    assert evs[3:-1] == events
    # after the stop the extruder comes back on with the next extruding move (not after a set point alone)
    assert evs[-1] == LinearMove(3, None if op == SET_TEMP else ExtruderOn(1.0))


def test_blocks_layers_and_state_across_ranges() -> None:
    rows = [(MOVEL, 0.1, 10, 0, 0, k // 3) for k in range(7)]
    p = _program(rows)
    walker = RowWalker(p, block_rows=3)
    first = list(walker.walk(0, 4))
    assert [ev for ev in first if isinstance(ev, Block)] == [Block(0, 3), Block(3, 4)]
    assert [ev.layer for ev in first if isinstance(ev, LayerStart)] == [0, 1]
    # the next range goes on from the state the first left: still extruding, layer 1 already announced
    second = list(walker.walk(4, 7))
    assert second == [Block(4, 7), LinearMove(4, None), LinearMove(5, None), LayerStart(2), LinearMove(6, None)]
    walker.extruder_reset()
    assert list(walker.walk(6, 7))[1] == LinearMove(6, ExtruderOn(1.0))


def test_unknown_instruction_is_a_typed_error() -> None:
    p = _program([(MOVEL, 0, 10, 0, 0, 0), (9, 0, 0, 0, 0, 0)])
    with pytest.raises(ValidationError) as err:
        _events(p)
    assert err.value.details["row"] == 1


def test_walk_covers_every_motion_row_of_a_plan() -> None:
    p = _program([(MOVEJ if k in (0, 9) else MOVEL, 0.1 * (k % 2), 10, 0, 0, 0) for k in range(10)])
    moves = [ev.row for ev in _events(p, block_rows=4) if isinstance(ev, (JointMove, LinearMove))]
    assert moves == list(np.flatnonzero(p.op <= MOVEL))


def test_runs_are_the_plain_linear_moves() -> None:
    # runs=True yields LinearRun for stretches of moves that switch nothing; expanded, the events are the same
    rng = np.random.default_rng(3)
    n = 5000
    ops = np.where(rng.random(n) < 0.003, MOVEJ, MOVEL)
    ops[rng.random(n) < 0.002] = WAIT
    flow = np.repeat(rng.choice([0.0, 0.1, 0.12], n // 50), 50) * (rng.random(n) > 0.002)
    speed = np.repeat(rng.choice([10.0, 20.0], n // 100), 100)
    layer = np.repeat(np.arange(n // 700 + 1), 700)[:n]
    p = _program([(int(o), float(f), float(v), 0.5, 0, int(k))
                  for o, f, v, k in zip(ops, flow, speed, layer, strict=True)])
    p.section[:300] = 0
    with_runs, reference = RowWalker(p, block_rows=1000, runs=True), RowWalker(p, block_rows=1000)
    expanded, expected, runs = [], [], 0
    for lo, hi in ((0, 1200), (1200, n)):          # two ranges: state carries over, a range starts afresh
        for ev in with_runs.walk(lo, hi):
            if isinstance(ev, LinearRun):
                runs += 1
                expanded += [LinearMove(i, None) for i in range(ev.start, ev.stop)]
            elif not isinstance(ev, Block):
                expanded.append(ev)
        expected += [ev for ev in reference.walk(lo, hi) if not isinstance(ev, Block)]
    assert expanded == expected
    assert runs > 20
