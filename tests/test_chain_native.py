"""The chain walk and the sag check of linear moves in C (fabric/native/chain.c) against numpy's: the walk to
the bit on every built-in arm (the KR 6's axes about -z and -x included), the check's rows and sags on
programs with moves that are not linear, not solved, after a row that is not solved, and with and without
the row before a chunk."""
from __future__ import annotations

import numpy as np
import pytest

from fabric import native
from fabric.motion.program import MOVEJ, MOVEL, Program
from fabric.planning import refine
from fabric.planning.refine import PrevRow, reach_bound_mm
from fabric.robot import chain_native
from fabric.robot.cell import Cell
from fabric.robot.chain_point import ChainPoint, _Joint
from fabric.robot.kinematics import IK_JOINT_LIMIT, IK_OK

pytestmark = pytest.mark.skipif(native.library("chain") is None, reason="no C compiler: numpy's path only")

CELLS = ["irb140", "kr6r700", "ur5", "ur10", "panda"]


def _numpy(walk: ChainPoint, q: np.ndarray) -> np.ndarray:
    walk.use_native = False
    try:
        return walk(q)
    finally:
        del walk.use_native


@pytest.mark.parametrize("name", CELLS)
def test_the_walk_is_numpys_to_the_bit(name: str) -> None:
    robot = Cell.builtin(name).robot
    walk = robot.chain_point
    assert walk is not None                                   # every built-in arm has one (the KR 6: -z, -x axes)
    q = np.random.default_rng(1).uniform(-20.0, 20.0, (20000, robot.nq))
    got = walk(q)
    np.testing.assert_array_equal(got, _numpy(walk, q))
    np.testing.assert_array_equal(walk(q[::3]), got[::3])     # rows apart in memory
    np.testing.assert_array_equal(walk(np.asfortranarray(q)), got)
    np.testing.assert_allclose(got[:200], robot.fk(q[:200])[:, :3, 3], atol=1e-9)


def _program(robot, n: int, seed: int) -> tuple[Program, np.ndarray]:
    """Rows along a random joint walk with steps of every size, their TCP on the plate; some rows MOVEJ, some
    not solved; the plate frame turned and moved."""
    rng = np.random.default_rng(seed)
    lo, hi = np.maximum(robot.lower_rad, -2.5), np.minimum(robot.upper_rad, 2.5)
    step = rng.normal(0.0, 1.0, (n, robot.nq)) * rng.choice([0.001, 0.01, 0.05], (n, 1))
    q = np.clip(0.5 * (lo + hi) + np.cumsum(step, axis=0), lo, hi)
    prog = Program.empty(n, robot.nq)
    prog.q_rad[:] = q
    prog.op[:] = np.where(rng.random(n) < 0.05, MOVEJ, MOVEL)
    c, s = np.cos(0.4), np.sin(0.4)
    prog.wobj = np.array([[c, -s, 0, 300.0], [s, c, 0, -50.0], [0, 0, 1, 20.0], [0, 0, 0, 1]])
    base = robot.tcp_xyz_mm(q)
    prog.xyz_mm[:] = (base - prog.wobj[:3, 3]) @ prog.wobj[:3, :3]           # the TCP in the plate frame
    prog.xyz_mm[:] += rng.normal(0.0, 0.02, (n, 3))                         # the line is not quite the arc's
    status = np.where(rng.random(n) < 0.03, IK_JOINT_LIMIT, IK_OK).astype(np.uint8)
    return prog, status


def _straying(prog, status, robot, prev, native_walk: bool) -> tuple[np.ndarray, np.ndarray]:
    walk = robot.chain_point
    walk.use_native = native_walk
    try:
        return refine._straying(prog, status, robot, 0.1, prev, reach_bound_mm(robot), None)
    finally:
        del walk.use_native


@pytest.mark.parametrize("name", CELLS)
def test_the_check_finds_numpys_rows_and_sags(name: str) -> None:
    robot = Cell.builtin(name).robot
    prog, status = _program(robot, 20000, seed=5)
    first = prog.q_rad[0] + 0.03
    for prev in (None, PrevRow(prog.xyz_mm[0] + 1.0, prog.quat_wxyz[0], first, IK_OK),
                 PrevRow(prog.xyz_mm[0], prog.quat_wxyz[0], first, IK_JOINT_LIMIT)):
        rows, sag = _straying(prog, status, robot, prev, True)
        want_rows, want_sag = _straying(prog, status, robot, prev, False)
        assert len(want_rows) > 100                              # the check has moves to report
        np.testing.assert_array_equal(rows, want_rows)
        np.testing.assert_allclose(sag, want_sag, rtol=0, atol=1e-9)
        assert (0 in rows) == (prev is not None and prev.status == IK_OK and 0 in want_rows)


def test_a_chain_longer_than_the_helper_takes_is_refused() -> None:
    walk = ChainPoint([_Joint(2, 1, np.eye(3), np.array([0.0, 0.0, 100.0]))] * 17, np.zeros(3))
    with pytest.raises(ValueError, match="17 joints"):
        chain_native.points(walk.packed(), np.zeros((3, 17)))
