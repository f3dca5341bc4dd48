"""The look-ahead's cruise caps in C (fabric/native/lookahead.c) against numpy's: the same caps, slowed rows,
limiting joints and moving rows, to the bit; and a whole program timed both ways."""
from __future__ import annotations

import numpy as np
import pytest

from fabric import native
from fabric.motion import lookahead, lookahead_native
from fabric.motion.testprog import square_program
from fabric.motion.timing import program_times
from fabric.robot.cell import Cell

pytestmark = pytest.mark.skipif(native.library("lookahead") is None, reason="no C compiler: numpy's path only")


def _both(*args):
    lookahead.use_native_caps = False
    try:
        want = lookahead._caps(*args)
    finally:
        lookahead.use_native_caps = True
    return lookahead._caps(*args), want


@pytest.mark.parametrize("nq", [6, 7])
def test_the_caps_are_numpys(nq: int) -> None:
    rng = np.random.default_rng(nq)
    n = 30000
    q = np.cumsum(rng.normal(0.0, 0.01, (n, nq)), axis=0)
    q[100:300] = q[99]                                          # rows that do not move
    q[400:500, 2] = q[399, 2] + 1e-13                           # a joint moving less than the threshold
    q[600:700, :] = q[599] + np.where(np.arange(nq) < 2, 0.02, 0.0)   # two joints at the same rate: the first
    seg = np.flatnonzero(rng.random(n) < 0.9)
    Ls = rng.uniform(0.1, 5.0, len(seg))
    Ls[seg >= 600] = np.where(seg[seg >= 600] < 700, 1.0, Ls[seg >= 600])
    cap = rng.choice([1e-3, 30.0, 1e6], len(seg))
    vlim = np.linspace(1.0, 2.6, nq)
    vlim[:2] = 1.5
    got, want = _both(cap, q, q[0] - 0.01, Ls, seg, vlim)
    for a, b in zip(got, want, strict=True):
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)
    assert want[1].any() and not want[1].all()                 # some segments slowed, some not
    assert np.all(want[2][(seg >= 600) & (seg < 700)] == 0)


def test_no_segments() -> None:
    q = np.zeros((5, 6))
    got, want = _both(np.zeros(0), q, q[0], np.zeros(0), np.zeros(0, np.intp), np.ones(6))
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a, b)


def test_rows_out_of_order_are_refused() -> None:
    q = np.zeros((5, 6))
    with pytest.raises(ValueError, match="ascending"):
        lookahead_native.caps(np.ones(2), q, q[0], np.ones(2), np.array([3, 1]), np.ones(6))


@pytest.mark.parametrize("name", ["irb140", "panda"])
def test_a_program_is_timed_the_same_both_ways(name: str) -> None:
    cell = Cell.builtin(name)
    prog = square_program(cell, size_mm=40, layers=40, layer_height_mm=0.4, speed_mm_s=400)   # 203 rows: 4 blocks
    got = program_times(prog, cell.robot, block_rows=64)
    lookahead.use_native_caps = False
    try:
        want = program_times(prog, cell.robot, block_rows=64)
    finally:
        lookahead.use_native_caps = True
    assert got.total_s == want.total_s
    np.testing.assert_array_equal(got.t_end_s, want.t_end_s)
    np.testing.assert_array_equal(got.slowed_rows, want.slowed_rows)
