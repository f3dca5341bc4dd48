"""The material on the plate (fabric.sim.material) and the twin's last guard: a run on a part never lays a bead
into it. Beads stacked, side by side, end to end or crossing are the print's normal squash; a bead laid along
one already there is not, and the twin faults before it even when nothing checked the run first."""
from __future__ import annotations

import numpy as np
import pytest

from fabric.motion.testprog import square_program
from fabric.robot.cell import Cell
from fabric.sim.material import NewBeads, PlateMaterial
from fabric.sim.twin import Twin

W, H = 0.5, 0.3


def _beads(*segments: tuple[tuple[float, float, float], tuple[float, float, float]]) -> NewBeads:
    a = np.array([s for s, _ in segments], dtype=float)
    b = np.array([e for _, e in segments], dtype=float)
    n = len(a)
    return NewBeads(a, b, np.full(n, W), np.full(n, H), np.arange(1, n + 1))


def _material(new: NewBeads) -> PlateMaterial:
    return PlateMaterial(new.start_mm, new.end_mm, new.width_mm, new.height_mm, np.zeros(len(new.row), np.int64))


def test_stacked_side_by_side_end_to_end_and_crossing_beads_are_not_into_the_material() -> None:
    part = _material(_beads(((0, 0, 0.3), (20, 0, 0.3))))
    for what, bead in {"a layer above": ((0, 0, 0.6), (20, 0, 0.6)),
                       "beside it (a width less 10 %)": ((0, 0.45, 0.3), (20, 0.45, 0.3)),
                       "end to end": ((20, 0, 0.3), (30, 0, 0.3)),
                       "crossing at 90 deg": ((10, -5, 0.3), (10, 5, 0.3)),
                       "crossing at 45 deg": ((5, -5, 0.3), (15, 5, 0.3))}.items():
        assert part.first_overlap(_beads(bead)) is None, what


def test_a_bead_laid_along_one_already_there_goes_into_it() -> None:
    part = _material(_beads(((0, 0, 0.3), (20, 0, 0.3)), ((0, 10, 0.3), (20, 10, 0.3))))
    new = _beads(((0, 5, 0.6), (20, 5, 0.6)), ((5, 10.1, 0.35), (15, 10.1, 0.35)), ((0, 0, 0.3), (3, 0, 0.3)))
    found = part.overlapping(new)
    assert [(o.new, o.existing) for o in found] == [(1, 1), (2, 0)]     # not the first: it is in the air
    assert found[0].length_mm == pytest.approx(10.0, abs=0.5)


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


def _print(cell: Cell, stop_after_beads: int | None = None) -> Twin:
    tw = Twin(cell)
    tw.load(square_program(cell, size_mm=20, layers=12, layer_height_mm=0.5, speed_mm_s=10, nozzle_c=200.0))
    tw.start()
    while tw.state == "printing":
        tw.advance(0.5)
        if stop_after_beads and len(tw.beads) >= stop_after_beads and tw.state == "printing":
            tw.stop()
    for _ in range(200):
        if not tw.moving:
            break
        tw.advance(1.0)
    return tw


def test_the_twin_faults_before_laying_a_bead_into_the_part(cell: Cell) -> None:
    """A restart at layer 3 of a finished 12-layer tower, forced past every check: it goes on where layer 3
    ends, and the twin stops before layer 4's first bead, faults with the reason, and the plate holds what
    it held."""
    tw = _print(cell)
    volume = tw.beads.total_volume_mm3
    beads = len(tw.beads)
    tw.start(from_layer=2)
    events = []
    for _ in range(400):
        events += tw.advance(0.5)
        if tw.state != "printing":
            break
    assert tw.state == "fault" and tw.reason.startswith("deposit guard: G-code line")
    assert "(layer 4)" in tw.reason and "its layer 4" in tw.reason
    fault = next(e for e in events if e.kind == "fault")
    assert fault.layer == 3
    assert len(tw.beads) == beads and tw.beads.total_volume_mm3 == pytest.approx(volume)


def test_going_on_where_a_stopped_part_ends_is_not_guarded(cell: Cell) -> None:
    tw = _print(cell, stop_after_beads=30)
    top = int(tw.beads.layer[-1])
    tw.start(from_layer=top + 1)
    for _ in range(2000):
        tw.advance(0.5)
        if tw.state != "printing":
            break
    assert tw.state == "idle" and tw.reason == "finished"
