"""The OPW family: parameters derived from URDFs, refusals of other arms, a cross-check with py-opw-kinematics."""
from __future__ import annotations

import numpy as np
import pytest

from fabric.robot.arm_family import IKFamilyMismatch
from fabric.robot.cell import PACKAGE_DIR
from fabric.robot.ik_family import detect_ik_family
from fabric.robot.joint_axes import joint_axes
from fabric.robot.kinematics import IK_OK, IK_SINGULAR, IRB140_ARM, pose_cols
from fabric.robot.model import IRB140_URDF, RobotModel
from fabric.robot.opw import OPWArm
from fabric.robot.opw_derive import derive_opw

KR6_URDF = PACKAGE_DIR / "robot" / "urdf" / "kr6r700.urdf"


@pytest.fixture(scope="module")
def irb() -> RobotModel:
    return RobotModel.from_urdf(IRB140_URDF)


@pytest.fixture(scope="module")
def kr6() -> RobotModel:
    return RobotModel.from_urdf(KR6_URDF, flange_frame="tool0", name="kr6r700")


def _arm(robot: RobotModel) -> OPWArm:
    arm = robot.family_choice.arm
    assert isinstance(arm, OPWArm)
    return arm


def test_irb140_parameters_are_abbs_figures(irb: RobotModel) -> None:
    p = _arm(irb).params
    assert p.lengths_mm() == pytest.approx({"a1": 70.0, "a2": 0.0, "b": 0.0, "c1": 352.0, "c2": 360.0,
                                            "c3": 380.0, "c4": 65.0}, abs=1e-9)
    np.testing.assert_allclose(np.degrees(p.offsets_rad), [0, 0, 90, 0, 0, 0], atol=1e-12)
    assert p.signs == (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)


def test_irb140_opw_model_equals_the_reference_closed_form(irb: RobotModel) -> None:
    rng = np.random.default_rng(30)
    q = rng.uniform(irb.lower_rad, irb.upper_rad, (2000, 6))
    np.testing.assert_allclose(_arm(irb).fk_flange(q), IRB140_ARM.fk_flange(q), atol=1e-9)


def test_kr6r700_parameters_are_the_published_ones(kr6: RobotModel) -> None:
    """KUKA KR 6 R700 sixx as commonly published for OPW solvers (mm): a1=25, a2=-35, b=0, c1=400, c2=315,
    c3=365, c4=80; joint offsets (0, -90, 0, 0, 0, 0) deg and axis flips (A1, A4, A6) in their convention."""
    p = _arm(kr6).params
    assert p.lengths_mm() == pytest.approx({"a1": 25.0, "a2": -35.0, "b": 0.0, "c1": 400.0, "c2": 315.0,
                                            "c3": 365.0, "c4": 80.0}, abs=1e-9)
    # ours: theta = sign * q + offset; the published (py-opw-kinematics) offsets enter with the other sign
    np.testing.assert_allclose(-np.degrees(p.offsets_rad), [0, -90, 0, 0, 0, 0], atol=1e-12)
    assert p.signs == (-1.0, 1.0, 1.0, -1.0, 1.0, -1.0)
    reach_mm = p.a1_mm + p.c2_mm + np.hypot(p.a2_mm, p.c3_mm)
    assert reach_mm == pytest.approx(706.7, abs=0.05)                # KUKA's published maximum reach


def test_kr6r700_limits_are_kukas(kr6: RobotModel) -> None:
    np.testing.assert_allclose(np.degrees(kr6.lower_rad), [-170, -190, -120, -185, -120, -350], atol=1e-9)
    np.testing.assert_allclose(np.degrees(kr6.upper_rad), [170, 45, 156, 185, 120, 350], atol=1e-9)
    np.testing.assert_allclose(np.degrees(kr6.vel_limit_rad_s), [360, 300, 360, 381, 388, 615], atol=1e-9)


def test_a_ur5_is_refused_with_the_condition_that_failed() -> None:
    ur5 = RobotModel.from_example_robot_data("ur5")
    with pytest.raises(IKFamilyMismatch) as exc:
        derive_opw(joint_axes(ur5.pin_model, ur5.flange_frame_id))
    assert exc.value.details["family"] == "opw"
    assert "axis 4 is parallel to axes 2 and 3" in str(exc.value) and "UR-type" in str(exc.value)
    assert ur5.ik_family == "ur" and "axis 4 is parallel" in ur5.family_choice.refused["opw"]


def test_an_offset_wrist_is_refused(irb: RobotModel) -> None:
    text = IRB140_URDF.read_text().replace('<origin xyz="0.380 0 0" rpy="0 0 0"/><axis xyz="0 1 0"/>',
                                           '<origin xyz="0.380 0.02 0" rpy="0 0 0"/><axis xyz="0 1 0"/>')
    bent = RobotModel.from_urdf(text)
    with pytest.raises(IKFamilyMismatch) as exc:
        derive_opw(joint_axes(bent.pin_model, bent.flange_frame_id))
    assert "axes 4, 5 and 6 do not meet in one point" in str(exc.value)
    assert exc.value.details["value"] == pytest.approx(20.0)
    assert bent.ik_family == "numeric"                               # and the arm still works, numerically
    q = np.radians([10, 20, -30, 40, 50, 60])
    qs, st = bent.ik(bent.fk(q), q)
    assert st[0] == IK_OK
    np.testing.assert_allclose(bent.fk(qs[0]), bent.fk(q), atol=1e-3)


def test_a_seven_axis_arm_is_neither_opw_nor_ur() -> None:
    panda = RobotModel.from_example_robot_data("panda")         # the hand's finger joints are dropped: 7 axes
    choice = detect_ik_family(panda.pin_model, panda.flange_frame_id, panda.lower_rad, panda.upper_rad)
    assert choice.family == "panda"                             # the 7-axis family (tests/test_ik_panda.py)
    assert choice.refused == {"opw": "needs 6 joints, the URDF has 7", "ur": "needs 6 joints, the URDF has 7"}


def test_base_and_flange_frames_other_than_the_models_are_absorbed(irb: RobotModel) -> None:
    """A URDF whose base is turned and lifted, and whose flange is turned, is still OPW and exact."""
    text = IRB140_URDF.read_text()
    text = text.replace('<origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/>',
                        '<origin xyz="0.1 -0.2 0.05" rpy="0.3 -0.2 0.7"/><axis xyz="0 0 1"/>')
    text = text.replace('<origin xyz="0.065 0 0" rpy="0 1.5707963267948966 0"/>',
                        '<origin xyz="0.065 0.01 0" rpy="0.2 1.2 -0.4"/>')
    odd = RobotModel.from_urdf(text)
    assert odd.ik_family == "opw"
    assert _arm(odd).params.lengths_mm()["c4"] == pytest.approx(65.0)
    rng = np.random.default_rng(31)
    q = rng.uniform(odd.lower_rad, odd.upper_rad, (500, 6))
    T = odd.fk(q)
    np.testing.assert_allclose(T, odd.frame_poses(q, odd.tcp_frame_id), atol=1e-9)
    qs, st = odd.ik(T, q[0])
    assert np.all((st == IK_OK) | (st == IK_SINGULAR))
    np.testing.assert_allclose(odd.fk(qs), T, atol=1e-8)


@pytest.mark.parametrize("name", ["irb140", "kr6r700"])
def test_cross_check_against_py_opw_kinematics(name: str, irb: RobotModel, kr6: RobotModel) -> None:
    """Same forward kinematics as an independent OPW solver, and the same set of IK solutions."""
    opw = pytest.importorskip("py_opw_kinematics")
    robot = irb if name == "irb140" else kr6
    arm = _arm(robot)
    p = arm.params
    model = opw.KinematicModel(a1=p.a1_mm, a2=p.a2_mm, b=p.b_mm, c1=p.c1_mm, c2=p.c2_mm, c3=p.c3_mm, c4=p.c4_mm,
                               offsets=tuple(-o for o in p.offsets_rad), flip_axes=tuple(s < 0 for s in p.signs))
    other = opw.Robot(model, degrees=False)
    rng = np.random.default_rng(32)
    q = rng.uniform(robot.lower_rad, robot.upper_rad, (2000, 6))
    end = arm.fk_flange(q) @ np.linalg.inv(arm.flange_T)          # the OPW end frame (base frames coincide)
    theirs = other.batch_forward(q).as_matrix()
    np.testing.assert_allclose(end, theirs, atol=1e-9)
    sols = other.reach(other.batch_forward(q)).joints                 # (n, 8, 6), NaN where none
    qb, reach, sing = arm.ik_branches_cols(pose_cols(end))
    regular = ~sing.any(axis=1)
    assert np.array_equal(reach, np.isfinite(sols).all(axis=2).any(axis=1, keepdims=True) & reach)
    for i in np.flatnonzero(regular)[:500]:
        a = qb[i, reach[i]]
        b = sols[i][np.isfinite(sols[i]).all(axis=1)]
        assert len(a) == len(b)
        d = a[:, None, :] - b[None, :, :]
        d -= 2.0 * np.pi * np.rint(d / (2.0 * np.pi))
        dist = np.max(np.abs(d), axis=2)
        assert dist.min(axis=1).max() < 1e-8 and dist.min(axis=0).max() < 1e-8    # same sets


@pytest.mark.parametrize("b_mm", [40.0, -25.0])
def test_a_shoulder_offset_b_solves_both_shoulders(kr6: RobotModel, b_mm: float) -> None:
    """With the arm's plane offset from axis 1 (b != 0, as on some Staubli and Fanuc arms) every branch,
    the back shoulder's too, lands on the target, and the set of solutions is an independent solver's."""
    import dataclasses
    arm = OPWArm(dataclasses.replace(_arm(kr6).params, b_mm=b_mm))
    rng = np.random.default_rng(33)
    q = rng.uniform(kr6.lower_rad, kr6.upper_rad, (2000, 6))
    end = arm.fk_flange(q) @ np.linalg.inv(arm.flange_T)
    qb, reach, sing = arm.ik_branches_cols(pose_cols(end))
    assert reach[:, 4:].any(axis=1).mean() > 0.5                   # the back shoulder is reached on many rows
    got = arm.fk_flange(qb[reach]) @ np.linalg.inv(arm.flange_T)
    np.testing.assert_allclose(got, np.repeat(end, reach.sum(axis=1), axis=0), atol=1e-8)
    opw = pytest.importorskip("py_opw_kinematics")
    p = arm.params
    model = opw.KinematicModel(a1=p.a1_mm, a2=p.a2_mm, b=p.b_mm, c1=p.c1_mm, c2=p.c2_mm, c3=p.c3_mm, c4=p.c4_mm,
                               offsets=tuple(-o for o in p.offsets_rad), flip_axes=tuple(s < 0 for s in p.signs))
    other = opw.Robot(model, degrees=False)
    np.testing.assert_allclose(end, other.batch_forward(q).as_matrix(), atol=1e-9)
    sols = other.reach(other.batch_forward(q)).joints
    for i in np.flatnonzero(~sing.any(axis=1))[:300]:
        a, b = qb[i, reach[i]], sols[i][np.isfinite(sols[i]).all(axis=1)]
        assert len(a) == len(b)
        d = a[:, None, :] - b[None, :, :]
        d -= 2.0 * np.pi * np.rint(d / (2.0 * np.pi))
        assert np.max(np.abs(d), axis=2).min(axis=1).max() < 1e-8
