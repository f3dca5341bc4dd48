"""The batched DLS IK of redundant arms of no closed-form family, and the N-joint program plumbing it feeds.

The Panda itself has a closed form now (``fabric/robot/panda.py``); the numeric fallback is tested on a Panda
whose A6 is moved 10 mm off A5, so that no family fits it, in the Panda cell's layout.
"""
from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
import pytest

from fabric import programs
from fabric.motion.program import Program, column_spec
from fabric.motion.program_file import FileSink, MemorySink
from fabric.planning.post.csv import csv_columns, write_csv
from fabric.robot.batch_dls import BatchDLSIK
from fabric.robot.cell import Cell
from fabric.robot.frames import make_T
from fabric.robot.kinematics import IK_OK
from fabric.robot.model import RobotModel
from fabric.robot.path_ik import solve_path


@pytest.fixture(scope="module")
def panda() -> Cell:
    return Cell.builtin("panda")


@pytest.fixture(scope="module")
def bent(panda: Cell) -> RobotModel:
    """The Panda with A6 10 mm off A5 (no closed form fits), its IK holding A3 at the cell's home."""
    from example_robot_data.robots_loader import ROBOTS
    loader = ROBOTS["panda"]()
    text, n = re.subn(r'(<joint name="panda_joint6".*?<origin rpy="[^"]*" xyz=")[^"]*(")', r"\g<1>0.01 0 0\g<2>",
                      Path(loader.df_path).read_text(), count=1, flags=re.S)
    assert n == 1
    share = Path(loader.model_path).resolve().parent.parent
    r = RobotModel(text, panda.robot.tool_T, "panda_link8", "panda-bent", [str(share)])
    r.set_posture(panda.home_q_rad, "panda_joint3")
    assert r.ik_family == "numeric" and isinstance(r.solver, BatchDLSIK)
    return r


def test_the_hand_and_fingers_are_dropped_and_the_arm_keeps_seven_joints() -> None:
    r = RobotModel.from_example_robot_data("panda")          # default flange: panda_hand; its fingers go
    assert r.nq == 7 and all("finger" not in n for n in r.joint_names)
    cut = RobotModel.from_example_robot_data("panda", flange_frame="panda_link8")   # the hand goes too
    assert "panda_hand" not in cut.urdf_text() and cut.nq == 7


def test_fk_is_pinocchios(bent: RobotModel) -> None:
    r = bent
    assert isinstance(r.solver, BatchDLSIK) and r.solver.hold == 2          # panda_joint3 held
    q = np.random.default_rng(3).uniform(r.lower_rad, r.upper_rad, (64, 7))
    np.testing.assert_allclose(r.fk(q), r.frame_poses(q, r.tcp_frame_id), atol=1e-9)


@pytest.mark.slow                         # 2.3 s (not the fast tier)
def test_round_trip_on_random_configurations(panda: Cell, bent: RobotModel) -> None:
    r = bent
    q = np.random.default_rng(11).uniform(r.lower_rad, r.upper_rad, (2000, 7))
    T = r.fk(q)
    qs, st = r.solver.solve_rows(T, np.broadcast_to(panda.home_q_rad, q.shape))     # type: ignore[union-attr]
    back = r.fk(qs)
    solved = (np.linalg.norm(back[:, :3, 3] - T[:, :3, 3], axis=1) < 1e-4) & r.within_limits(qs)
    assert solved.mean() >= 0.99                      # the unbent Panda by this solver: 99.74 % of 10,000
    assert np.all(solved[st == IK_OK])


def test_a_path_is_continuous_held_and_independent_of_the_seed(panda: Cell, bent: RobotModel) -> None:
    r = bent
    t = np.linspace(0.0, 2.0 * np.pi, 3000)
    local = np.stack([125.0 + 100.0 * np.cos(t), 125.0 + 100.0 * np.sin(t), 5.0 + 10.0 * t], axis=1)
    W = panda.wobj_T()
    R = panda.home_tcp_T()[:3, :3]
    T = make_T(np.broadcast_to(R, (len(t), 3, 3)), local @ W[:3, :3].T + W[:3, 3])
    q, st = r.ik(T, panda.home_q_rad)
    assert np.all(st == IK_OK)
    np.testing.assert_allclose(r.fk(q)[:, :3, 3], T[:, :3, 3], atol=1e-4)
    np.testing.assert_allclose(q[:, 2], panda.home_q_rad[2])                     # the redundancy held
    assert np.abs(np.diff(q, axis=0)).max() < np.radians(2.0)                    # 0.2 mm steps, no jump
    q2, _ = r.ik(T, q[len(q) // 2])                                              # another seed, same joints
    np.testing.assert_allclose(q2, q, atol=1e-6)


def test_path_ik_with_the_free_nozzle_rotation(panda: Cell, bent: RobotModel) -> None:
    W = panda.wobj_T()
    u = np.linspace(0.0, 250.0, 6)
    X, Y = np.meshgrid(u, u)
    pts = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, 0.3)])
    res = solve_path(bent, pts @ W[:3, :3].T + W[:3, 3], [0.0, 0.0, -1.0], panda.home_q_rad)
    assert res.feasible_r == 1.0 and res.q_rad.shape == (X.size, 7)


def test_programs_carry_any_number_of_joints(tmp_path) -> None:
    p = Program.empty(3, nq=7)
    p.q_rad[:] = np.arange(21.0).reshape(3, 7)
    assert p.nq == 7 and column_spec(7)["q_rad"] == ("f8", (7,))
    back = programs.program_from_msg(programs.program_to_msg(p))
    np.testing.assert_array_equal(back.q_rad, p.q_rad)
    for sink in (MemorySink(nq=7), FileSink(tmp_path / "cols", nq=7)):
        sink.append(p.columns())
        prog, _ = sink.finish(p.wobj, {})
        np.testing.assert_array_equal(prog.q_rad, p.q_rad)
    p.op[:] = 1
    out = io.StringIO()
    write_csv(p, out)
    assert out.getvalue().splitlines()[0].split(",") == csv_columns(7)
    assert csv_columns(7)[8:15] == [f"q{j}_deg" for j in range(1, 8)]
    with pytest.raises(ValueError, match="q_rad"):
        Program(**{**Program.empty(2).columns(), "q_rad": np.zeros((3, 7))})
