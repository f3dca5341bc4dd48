"""The Panda-type closed form (7 axes, A7 the redundancy parameter): detection, round trips, branches, toolpaths."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from fabric.robot.arm_family import IKFamilyMismatch
from fabric.robot.batch_dls import BatchDLSIK
from fabric.robot.cell import CELLS_DIR, Cell
from fabric.robot.closed_form import ClosedFormIK
from fabric.robot.frames import make_T, rot_z
from fabric.robot.ik_family import detect_ik_family, panda_arm
from fabric.robot.joint_axes import joint_axes
from fabric.robot.joint_jumps import joint_jumps
from fabric.robot.kinematics import IK_JUMP, IK_OK, IK_SINGULAR, pose_cols
from fabric.robot.model import DEFAULT_TOOL_T, RobotModel
from fabric.robot.panda import PandaArm
from fabric.robot.panda_derive import derive_panda
from fabric.robot.path_ik import solve_path
from fabric.wire.errors import ConfigError

from support.ik_checks import assert_tracking_equals_full_rule

N = 10_000
POS_TOL_MM = 1e-3             # issue 20: 1e-6 m ...
ROT_TOL_RAD = 1e-6            # ... and 1e-6 rad


@pytest.fixture(scope="module")
def panda() -> Cell:
    return Cell.builtin("panda")


def _arm(cell: Cell) -> PandaArm:
    cf = cell.robot.closed_form
    assert cf is not None and isinstance(cf.arm, PandaArm)
    return cf.arm


def _cf(robot: RobotModel) -> ClosedFormIK:
    assert robot.closed_form is not None
    return robot.closed_form


def _rotation_error_rad(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    f = np.sqrt(np.sum((Ra - Rb) ** 2, axis=(1, 2)))
    return 2.0 * np.arcsin(np.minimum(1.0, f / (2.0 * np.sqrt(2.0))))


def _bent_panda(joint: str, xyz: str) -> RobotModel:
    """The example-robot-data Panda with ``joint``'s origin moved to ``xyz`` (metres): a 7-axis arm of no family."""
    from example_robot_data.robots_loader import ROBOTS
    loader = ROBOTS["panda"]()
    text = Path(loader.df_path).read_text()
    text, n = re.subn(rf'(<joint name="{joint}".*?<origin rpy="[^"]*" xyz=")[^"]*(")', rf"\g<1>{xyz}\g<2>", text,
                      count=1, flags=re.S)
    assert n == 1
    share = Path(loader.model_path).resolve().parent.parent
    return RobotModel(text, DEFAULT_TOOL_T, "panda_link8", "panda-bent", [str(share)])


def test_the_panda_cell_is_detected_with_its_geometry(panda: Cell) -> None:
    r = panda.robot
    assert r.ik_family == "panda" and isinstance(r.solver, ClosedFormIK) and r.closed_form is r.solver
    assert r.family_choice.refused == {"opw": "needs 6 joints, the URDF has 7", "ur": "needs 6 joints, the URDF has 7"}
    assert r.family_choice.parameters() == {"d1_mm": 333.0, "d3_mm": 316.0, "a4_mm": 82.5, "a5_mm": 82.5,
                                            "d5_mm": 384.0, "a7_mm": 88.0, "dF_mm": 107.0, "offset2_deg": 0.0}
    assert r.hold_joint is not None and r.joint_names[r.hold_joint] == "panda_joint7" and r.closed_form is not None
    assert r.closed_form.free_rad == pytest.approx(panda.home_q_rad[6])          # A7 held at home (45 deg)
    assert panda.to_dict()["robot"]["redundancy_joint"] == "panda_joint7"
    q = np.random.default_rng(1).uniform(r.lower_rad, r.upper_rad, (200, 7))
    np.testing.assert_allclose(r.fk(q), r.frame_poses(q, r.tcp_frame_id), atol=1e-9)   # FK is Pinocchio's


def test_round_trip_of_10000_random_configurations(panda: Cell) -> None:
    """FK -> IK (A7 given: the original one) -> FK within 1e-6 m and 1e-6 rad, inside the limits.

    Success is counted on every row; a row flagged ``IK_SINGULAR`` (elbow stretched or folded, the two wrist
    solutions within 1 % of meeting, axes 1 and 3 within 0.01 of aligned) is solved exactly all the same.
    """
    r = panda.robot
    q = np.random.default_rng(101).uniform(r.lower_rad, r.upper_rad, (N, 7))
    T = r.fk(q)
    qs, st = _cf(r).solve(T, q[0], q[:, 6])                   # scattered targets, each with its own A7
    back = r.fk(qs)
    pos_mm = np.linalg.norm(back[:, :3, 3] - T[:, :3, 3], axis=1)
    rot_rad = _rotation_error_rad(back[:, :3, :3], T[:, :3, :3])
    solved = (pos_mm <= POS_TOL_MM) & (rot_rad <= ROT_TOL_RAD) & r.within_limits(qs)
    assert solved.mean() >= 0.997 and solved.all()            # measured: 100 %
    singular = st == IK_SINGULAR
    assert np.all(st[~singular] == IK_OK) and singular.mean() < 0.05
    np.testing.assert_array_equal(qs[:, 6], q[:, 6])           # A7 is the one given
    assert pos_mm.max() <= 1e-8 and rot_rad.max() <= 1e-12     # far inside the bounds


def test_the_producing_configuration_is_one_of_the_8_branches(panda: Cell) -> None:
    r = panda.robot
    arm = _arm(panda)
    q = np.random.default_rng(102).uniform(r.lower_rad, r.upper_rad, (N, 7))
    C = pose_cols(r.fk_flange(q))
    qb, reach, sing = arm.ik_branches_cols(C, None, q[:, 6])
    d = qb - q[:, None, :]
    d -= 2.0 * np.pi * np.rint(d / (2.0 * np.pi))
    nearest = np.min(np.max(np.abs(d), axis=2), axis=1)
    regular = ~sing.any(axis=1)
    assert regular.mean() > 0.5 and nearest[regular].max() < 1e-9
    assert nearest.max() < 1e-5                                # singular rows: still the same configuration
    assert np.all(reach.sum(axis=1) >= 4)                      # both wrists and both shoulders of the elbow
    for b in range(8):                                         # and every branch found is a solution
        Tb = r.fk_flange(qb[reach[:, b], b])
        np.testing.assert_allclose(Tb, r.fk_flange(q[reach[:, b]]), atol=1e-8)


def test_branch_tracking_equals_the_full_8_branch_rule(panda: Cell) -> None:
    """The fast path (one branch while provably nearest) picks what the full 8-branch rule picks."""
    r = panda.robot
    s = np.linspace(0.0, 1.0, 3000)[:, None]
    span = np.minimum(r.upper_rad, np.pi) - np.maximum(r.lower_rad, -np.pi)
    wave = np.sin(2 * np.pi * s * np.array([1.0, 1.5, 0.7, 2.0, 1.2, 3.0, 0.0]))
    smooth = np.clip(panda.home_q_rad + 0.15 * span * wave, r.lower_rad, r.upper_rad)
    scattered = np.random.default_rng(103).uniform(r.lower_rad, r.upper_rad, (3000, 7))
    scattered[:, 6] = panda.home_q_rad[6]                      # A7 held, as the planner does
    T = r.fk(np.concatenate([smooth, scattered, smooth[::-1]]))
    assert_tracking_equals_full_rule(r, T, smooth, panda.home_q_rad[6])


def test_a7_is_an_explicit_per_row_input(panda: Cell) -> None:
    """A7 given per row is kept, and the rest of the arm follows it; a value outside A7's limits is refused."""
    r = panda.robot
    cf = r.closed_form
    assert cf is not None
    q = np.tile(panda.home_q_rad, (200, 1))
    q[:, 6] = np.linspace(-1.0, 2.0, 200)                      # the nozzle spun about itself
    q[:, 0] = np.linspace(-0.3, 0.3, 200)
    T = r.fk(q)
    qs, st = cf.solve(T, q[0], q[:, 6])
    assert np.all(st == IK_OK)
    np.testing.assert_allclose(qs, q, atol=1e-9)
    _, st = cf.solve(T[:5], q[0], np.radians(170.0))           # A7 beyond its +-166 deg
    assert np.all(st != IK_OK)


def test_a_toolpath_over_the_plate_is_solved_without_jumps(panda: Cell) -> None:
    """Serpentine layers over the whole plate (1 mm steps) through the planner's path IK: all solved, no jump."""
    r = panda.robot
    W = panda.wobj_T()
    x = np.arange(0.0, 250.0 + 1e-9, 1.0)
    layers = []
    for k, z in enumerate((0.3, 100.0, 200.0)):
        rows = [np.column_stack([x if i % 2 == 0 else x[::-1], np.full(x.size, y), np.full(x.size, z)])
                for i, y in enumerate(np.arange(0.0, 250.0 + 1e-9, 12.5))]
        layers.append(np.concatenate(rows if k % 2 == 0 else rows[::-1]))
    local = np.concatenate(layers)
    xyz = local @ W[:3, :3].T + W[:3, 3]
    res = solve_path(r, xyz, [0.0, 0.0, -1.0], panda.home_q_rad)
    assert res.feasible_r == 1.0 and not np.any(res.status == IK_JUMP)
    np.testing.assert_allclose(r.fk(res.q_rad)[:, :3, 3], xyz, atol=1e-8)
    np.testing.assert_allclose(r.fk(res.q_rad)[:, :3, 2], np.tile([0.0, 0.0, -1.0], (len(xyz), 1)), atol=1e-12)
    np.testing.assert_allclose(res.q_rad[:, 6], panda.home_q_rad[6])            # A7 held
    step = np.abs(np.diff(res.q_rad, axis=0)).max(axis=1)
    in_layer = np.diff(local[:, 2]) == 0.0                     # (a layer change is a long travel move)
    assert np.degrees(step[in_layer]).max() < 5.0              # 1 mm moves and 12.5 mm line changes
    # a configuration change inside the path is caught by the jump test
    T = r.fk(res.q_rad)
    cf = r.closed_form
    assert cf is not None
    qb, ok, _, _ = cf.branches(r.fk_flange(res.q_rad[100:101]))
    other = np.flatnonzero(ok[0] & (np.abs(qb[0] - res.q_rad[100]).max(axis=1) > 0.1))
    assert len(other)
    q_bad = res.q_rad.copy()
    q_bad[100:] = qb[0, other[0]]                            # row 100 on another branch from there on
    q_bad[101:] = res.q_rad[101:]
    assert np.flatnonzero(joint_jumps(r, q_bad, T)).tolist() == [100, 101]


def test_the_raster_through_robot_ik(panda: Cell) -> None:
    """The benchmark's raster (nozzle down, turned as at home) through ``RobotModel.ik``: every row OK, continuous."""
    r = panda.robot
    side = 100
    t = np.arange(side * side)
    row, col = t // side, t % side
    col = np.where(row % 2 == 0, col, side - 1 - col)
    local = np.stack([250.0 * col / (side - 1), 250.0 * row / (side - 1), np.full(t.size, 1.0)], axis=1)
    W = panda.wobj_T()
    R = panda.home_tcp_T()[:3, :3]
    T = np.broadcast_to(np.eye(4), (t.size, 4, 4)).copy()
    T[:, :3, :3], T[:, :3, 3] = R, local @ W[:3, :3].T + W[:3, 3]
    q, st = r.ik(T, panda.home_q_rad)
    assert np.all(st == IK_OK)
    np.testing.assert_allclose(r.fk(q), T, atol=1e-8)
    assert np.degrees(np.abs(np.diff(q, axis=0)).max()) < 3.0


def test_the_shoulders_gimbal_lock_holds_a1(panda: Cell) -> None:
    """Upper arm on axis 1 (A2 = 0): only A1 + A3 is defined; A1 is held at the previous row's value."""
    r = panda.robot
    q = np.array([[0.3, 0.0, 0.4, -1.5, 0.2, 1.8, 0.7]])
    seed = np.array([0.1, 0.2, 0.4, -1.4, 0.2, 1.8, 0.7])
    qs, st = _cf(r).solve(r.fk(q), seed, q[:, 6])
    assert st[0] == IK_SINGULAR
    assert qs[0, 0] == pytest.approx(0.1, abs=1e-12) and qs[0, 0] + qs[0, 2] == pytest.approx(0.7, abs=1e-9)
    np.testing.assert_allclose(r.fk(qs), r.fk(q), atol=1e-9)


@pytest.mark.parametrize("joint, xyz, condition", [
    ("panda_joint6", "0.01 0 0", "axes 5 and 6 do not meet"),
    ("panda_joint3", "0.01 -0.316 0", "axes 1, 2 and 3 do not meet in one point"),
])
def test_a_seven_axis_arm_of_another_kind_is_refused(joint: str, xyz: str, condition: str) -> None:
    """A Panda bent 10 mm off the family is refused naming the condition, and falls back to the batched DLS."""
    bent = _bent_panda(joint, xyz)
    with pytest.raises(IKFamilyMismatch) as exc:
        derive_panda(joint_axes(bent.pin_model, bent.flange_frame_id))
    assert exc.value.details["family"] == "panda" and condition in str(exc.value)
    assert str(exc.value).startswith("not a PANDA-type arm: ")
    assert exc.value.details["value"] == pytest.approx(10.0)
    assert bent.ik_family == "numeric" and condition in bent.family_choice.refused["panda"]
    assert isinstance(bent.solver, BatchDLSIK) and bent.closed_form is None


def test_a_six_axis_arm_is_refused() -> None:
    ur5 = RobotModel.from_example_robot_data("ur5")
    with pytest.raises(IKFamilyMismatch) as exc:
        panda_arm(ur5.pin_model, ur5.flange_frame_id, ur5.lower_rad, ur5.upper_rad)
    assert exc.value.details["condition"] == "needs 7 joints, the URDF has 6"
    choice = detect_ik_family(ur5.pin_model, ur5.flange_frame_id, ur5.lower_rad, ur5.upper_rad)
    assert choice.family == "ur" and choice.refused == {"opw": choice.refused["opw"]}   # ur wins before panda


def test_the_hand_as_flange_is_the_same_family() -> None:
    """example-robot-data's default flange (``panda_hand``, turned -45 deg about A7) is the same family."""
    r = RobotModel.from_example_robot_data("panda")
    assert r.flange_frame == "panda_hand" and r.ik_family == "panda"
    arm = r.family_choice.arm
    assert isinstance(arm, PandaArm)
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)                 # its end frame is the hand's: x turned -45 deg
    np.testing.assert_allclose(arm.params.end_T[:3, :3], [[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]], atol=1e-12)
    q = np.random.default_rng(5).uniform(r.lower_rad, r.upper_rad, (500, 7))
    T = r.fk(q)
    qs, _ = _cf(r).solve(T, q[0], q[:, 6])
    np.testing.assert_allclose(r.fk(qs), T, atol=1e-8)


@pytest.mark.slow                         # 1.4 s (not the fast tier)
def test_the_redundancy_joint_must_be_the_families(panda: Cell) -> None:
    text = (CELLS_DIR / "panda.toml").read_text()
    with pytest.raises(ConfigError) as exc:
        Cell.from_toml_text(text.replace('redundancy_joint = "panda_joint7"', 'redundancy_joint = "panda_joint3"'))
    assert exc.value.details["key"] == "robot.redundancy_joint" and "panda_joint7" in str(exc.value)
    unnamed = Cell.from_toml_text(re.sub(r'redundancy_joint = "panda_joint7".*\n', "", text))
    assert unnamed.robot.closed_form is not None and unnamed.robot.closed_form.free_rad == pytest.approx(np.pi / 4)
    r = panda.robot                                            # narrowed limits rebuild the solver, A7 still held
    upper = r.upper_rad.copy()
    upper[0] = 1.0
    narrowed = Cell.builtin("panda").robot.with_limits(upper_rad=upper)
    assert narrowed.closed_form is not None and narrowed.closed_form.free_rad == pytest.approx(np.pi / 4)
    np.testing.assert_allclose(narrowed.closed_form.upper_rad, upper)


def test_cross_check_against_panda_py(panda: Cell) -> None:
    """Same forward kinematics as libfranka's model (``panda_py.fk``, up to its fixed hand offset), and every exact
    solution of its analytical IK (He & Liu's solver, ``panda_py.ik_full``: up to 4 per pose and A7) is one of ours.

    ``panda_py.fk`` puts its end effector 103.0 mm beyond the flange while ``ik_full`` assumes the hand's 103.4 mm
    (libfranka's default ``F_T_EE``), so the IK is given the pose with 103.4 mm; its few solutions that do not
    reproduce the pose (near its own singular cases) are counted, not compared.
    """
    panda_py = pytest.importorskip("panda_py")
    r = panda.robot
    q = np.random.default_rng(33).uniform(r.lower_rad, r.upper_rad, (2000, 7))
    ours = r.fk_flange(q)
    theirs = np.stack([panda_py.fk(qi) for qi in q])
    theirs[:, :3, 3] *= 1000.0
    np.testing.assert_allclose(ours @ (np.linalg.inv(ours[0]) @ theirs[0]), theirs, atol=1e-9)
    ee_ik = make_T(rot_z(-np.pi / 4), [0.0, 0.0, 103.4])
    qb, reach, sing = _arm(panda).ik_branches_cols(pose_cols(ours), None, q[:, 6])
    rows, sols = [], []
    for i in np.flatnonzero(~sing.any(axis=1)):
        T = ours[i] @ ee_ik
        T[:3, 3] /= 1000.0
        found = np.asarray(panda_py.ik_full(T, q[i], q[i, 6]))
        found = found[np.isfinite(found).all(axis=1)]
        rows += [i] * len(found)
        sols.append(found)
    row, sol = np.array(rows), np.concatenate(sols)
    exact = np.abs(r.fk_flange(sol) - ours[row]).max(axis=(1, 2)) <= 1e-6
    assert len(sol) > 4000 and exact.mean() >= 0.98          # measured: 5,116 of 5,166 exact, all of them ours
    d = sol[exact, None, :] - qb[row[exact]]
    d -= 2.0 * np.pi * np.rint(d / (2.0 * np.pi))
    dist = np.where(reach[row[exact]], np.abs(d).max(axis=2), np.inf)
    assert dist.min(axis=1).max() < 1e-8
