"""The path IK's branch tracking in C (fabric/native/armik.c) against numpy's, for the OPW, UR and Panda cells.

Both paths must give the same joints and statuses on every kind of row: a smooth path (tracking), scattered
targets (the full 8-branch method row after row), rows out of reach or past a joint limit, a path through the
stretched elbow (two branches close together) and a row whose A1 is undefined (held: numpy's path answers).
"""
from __future__ import annotations

import numpy as np
import pytest

from fabric import native
from fabric.robot.cell import Cell
from fabric.robot.closed_form import ClosedFormIK
from fabric.robot.kinematics import IK_OK, pose_cols
from fabric.robot.opw import OPWArm

pytestmark = pytest.mark.skipif(native.library("armik") is None, reason="no C compiler: numpy's path only")

CELLS = ["irb140", "kr6r700", "ur5", "ur10", "panda"]


def _cf(cell: Cell) -> ClosedFormIK:
    cf = cell.robot.closed_form
    assert cf is not None
    return cf


def _solve(cf: ClosedFormIK, C: np.ndarray, seed: np.ndarray, use_native: bool) -> tuple[np.ndarray, np.ndarray]:
    cf.use_native = use_native
    try:
        return cf.ik_cols(C, seed)
    finally:
        cf.use_native = True


def _same(cf: ClosedFormIK, C: np.ndarray, seed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    assert cf.native_track() is not None, "the C tracking serves this family"
    qa, sa = _solve(cf, C, seed, True)
    qb, sb = _solve(cf, C, seed, False)
    np.testing.assert_array_equal(sa, sb)
    np.testing.assert_allclose(qa, qb, rtol=0, atol=1e-12)
    return qa, sa


def _held(cf: ClosedFormIK, q: np.ndarray) -> np.ndarray:
    """``q`` with a redundant arm's parameter joint (the Panda's A7) at the value the solver holds."""
    if cf.free_joint is not None:
        q[:, cf.free_joint] = cf.free_rad
    return q


def _path(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, knots: int, steps: int) -> np.ndarray:
    nq = len(lo)
    q0 = lo + (hi - lo) * rng.uniform(0.2, 0.8, (knots, nq))
    t = np.linspace(0.0, 1.0, steps)[:, None, None]
    return (q0[:-1][None] * (1 - t) + q0[1:][None] * t).transpose(1, 0, 2).reshape(-1, nq)


@pytest.fixture(scope="module", params=CELLS)
def cell(request: pytest.FixtureRequest) -> Cell:
    return Cell.builtin(request.param)


def test_a_smooth_path_and_scattered_targets_give_numpys_joints(cell: Cell) -> None:
    cf = _cf(cell)
    rng = np.random.default_rng(7)
    lo, hi = cell.robot.lower_rad, cell.robot.upper_rad
    path = _held(cf, _path(rng, lo, hi, 60, 120))
    scattered = _held(cf, rng.uniform(np.maximum(lo, -np.pi), np.minimum(hi, np.pi), (6000, len(lo))))
    for q in (path, scattered):
        C = pose_cols(cf.fk_flange(q), cf._end_inv)
        _, st = _same(cf, C, q[0])
        assert np.mean(st == IK_OK) > 0.9


def test_rows_out_of_reach_and_past_a_limit_give_numpys_statuses(cell: Cell) -> None:
    cf = _cf(cell)
    rng = np.random.default_rng(11)
    q = _held(cf, _path(rng, cell.robot.lower_rad, cell.robot.upper_rad, 20, 200))
    C = pose_cols(cf.fk_flange(q), cf._end_inv)
    C[0:3, 500:700] *= 3.0                             # far out of reach
    C[0:3, 1500:1510] = 0.0                            # the base origin
    q_wide = q.copy()
    q_wide[2000:2200, 1] += 2.5                        # A2 past its limit on some rows
    C[:, 2000:2200] = pose_cols(cf.fk_flange(q_wide[2000:2200]), cf._end_inv)
    _, st = _same(cf, C, q[0])
    assert {int(s) for s in np.unique(st)} > {IK_OK}


@pytest.mark.slow                         # 1 s per cell (not the fast tier)
def test_the_stretched_elbow_takes_the_nearest_branch(cell: Cell) -> None:
    """Through the stretched elbow two branches pass close together: each row takes the allowed branch
    nearest the row before (a brute-force chain over all 8 branches), in both paths. (numpy's path once
    bounded a UR arm's elbow gap by the other wrist's elbows and kept the farther branch.)"""
    cf = _cf(cell)
    rng = np.random.default_rng(1)
    lo, hi = cell.robot.lower_rad, cell.robot.upper_rad
    q = _held(cf, _path(rng, lo, hi, 200, 100))
    C = pose_cols(cf.fk_flange(q), cf._end_inv)
    got, _ = _same(cf, C, q[0])
    qb, ok, _reach, _ = cf.branches_cols(C)
    prev = q[0]
    for i in range(len(q)):
        if not ok[i].any():
            break
        d = np.where(ok[i], np.sum(((qb[i] - prev + np.pi) % (2 * np.pi) - np.pi) ** 2, axis=1), np.inf)
        nearest = qb[i, int(np.argmin(d))]
        if cf.multi.any():                               # multi-turn joints are unwrapped after the choice
            np.testing.assert_allclose(np.angle(np.exp(1j * (got[i] - nearest))), 0.0, atol=1e-9, err_msg=f"row {i}")
        else:
            np.testing.assert_allclose(got[i], nearest, atol=1e-9, err_msg=f"row {i}")
        prev = nearest


def test_a_row_with_a1_undefined_is_held_by_numpys_path() -> None:
    cell = Cell.builtin("irb140")                        # an OPW arm with b = 0: A1 is undefined on its axis
    cf = _cf(cell)
    seed = np.radians([30.0, 10.0, 20.0, 0.0, 40.0, 0.0])
    arm = cf.arm
    assert isinstance(arm, OPWArm)
    T = cf.fk_flange(np.stack([seed, seed]))
    T[1, :3, :3] = np.diag([-1.0, 1.0, -1.0])            # nozzle straight down ...
    T[1, :3, 3] = [0.0, 0.0, 600.0] + arm.c4 * T[1, :3, 2]   # ... with the wrist centre on axis 1
    C = pose_cols(T, cf._end_inv)
    out = np.empty((6, 2))
    flags = [np.empty(2, dtype=bool) for _ in range(3)]
    fast = cf.native_track()
    assert fast is not None and not fast.track(C, seed, cf.max_rows, out, *flags)
    q, _ = _same(cf, C, seed)
    assert q[1, 0] == pytest.approx(q[0, 0])             # A1 held from the row before


def test_the_pandas_a7_given_per_row_gives_numpys_joints() -> None:
    cf = _cf(Cell.builtin("panda"))
    rng = np.random.default_rng(5)
    lo, hi = cf.lower_rad, cf.upper_rad
    q = _path(rng, lo, hi, 30, 100)
    C = pose_cols(cf.fk_flange(q), cf._end_inv)
    fast = cf.native_track()
    assert fast is not None
    got = []
    for use_native in (True, False):
        cf.use_native = use_native
        try:
            got.append(cf.ik_cols(C, q[0], q_free=q[:, 6]))
        finally:
            cf.use_native = True
    np.testing.assert_array_equal(got[0][1], got[1][1])
    np.testing.assert_allclose(got[0][0], got[1][0], rtol=0, atol=1e-12)
    assert np.mean(got[0][1] == IK_OK) > 0.9
    np.testing.assert_allclose(got[0][0][:, 6], q[:, 6], atol=1e-12)     # A7 as given


def test_a_wrist_winding_past_its_limits_is_placed_as_numpy_places_it() -> None:
    """A6 of the UR5 (a multi-turn joint, +-360 deg) turned on and on along a path: unwrapped from the seed
    and shifted back by whole turns where the wind-up would pass a limit, the same in both paths."""
    cf = _cf(Cell.builtin("ur5"))
    assert cf.multi[5]
    q = np.tile(np.radians([10.0, -80.0, 90.0, -100.0, -90.0, 0.0]), (3000, 1))
    q[:, 5] = np.linspace(0.0, 5.5 * np.pi, len(q))              # nearly three turns, past +360 deg
    q[:, 0] = np.linspace(0.0, -7.0 * np.pi, len(q))             # A1 the other way, past -360 deg
    C = pose_cols(cf.fk_flange(q), cf._end_inv)
    got, st = _same(cf, C, q[0])
    assert np.all(st == IK_OK)
    for j in (0, 5):
        assert cf.lower_rad[j] - 1e-9 <= got[:, j].min() and got[:, j].max() <= cf.upper_rad[j] + 1e-9
        np.testing.assert_allclose(np.angle(np.exp(1j * (got[:, j] - q[:, j]))), 0.0, atol=1e-9)
