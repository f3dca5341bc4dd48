"""The UR family: DH parameters derived from the example-robot-data URDFs, the wrist hold, and a cross-check
against ur-analytic-ik."""
from __future__ import annotations

import numpy as np
import pytest

from fabric.robot.arm_family import IKFamilyMismatch
from fabric.robot.joint_axes import joint_axes
from fabric.robot.kinematics import IK_OK, IK_SINGULAR, pose_cols
from fabric.robot.model import IRB140_URDF, RobotModel
from fabric.robot.ur import URArm
from fabric.robot.ur_derive import derive_ur

# Universal Robots' published DH lengths (mm), with a2, a3 as distances (UR lists them as -425, -392.25 ...)
UR_DH_MM = {
    "ur5": {"d1": 89.159, "a2": 425.0, "a3": 392.25, "d4": 109.15, "d5": 94.65, "d6": 82.3},
    "ur10": {"d1": 127.3, "a2": 612.0, "a3": 572.3, "d4": 163.941, "d5": 115.7, "d6": 92.2},
}


@pytest.fixture(scope="module", params=["ur5", "ur10"])
def robot(request: pytest.FixtureRequest) -> RobotModel:
    return RobotModel.from_example_robot_data(request.param)


def _arm(robot: RobotModel) -> URArm:
    arm = robot.family_choice.arm
    assert isinstance(arm, URArm)
    return arm


def test_dh_lengths_are_universal_robots_figures(robot: RobotModel) -> None:
    assert robot.ik_family == "ur"
    assert _arm(robot).params.lengths_mm() == pytest.approx(UR_DH_MM[robot.name], abs=1e-9)


def test_an_opw_arm_is_refused() -> None:
    irb = RobotModel.from_urdf(IRB140_URDF)
    with pytest.raises(IKFamilyMismatch) as exc:
        derive_ur(joint_axes(irb.pin_model, irb.flange_frame_id))
    assert exc.value.details["family"] == "ur"
    assert str(exc.value) == "not a UR-type arm: axes 1 and 2 do not meet (distance, mm) (70)"
    assert irb.ik_family == "opw"


def test_exact_wrist_singularity_holds_a6(robot: RobotModel) -> None:
    qa = np.array([0.3, -1.2, 1.4, -1.9, -0.8, 0.7])
    qb = np.array([0.35, -1.1, 1.3, -1.8, 0.0, 1.1])                     # q5 = 0: axes 4 and 6 parallel
    qs, st = robot.ik(robot.fk(np.stack([qa, qb])), qa)
    assert st.tolist() == [IK_OK, IK_SINGULAR]
    assert qs[1, 5] == pytest.approx(0.7)                                 # A6 held from the row before
    np.testing.assert_allclose(robot.fk(qs[1]), robot.fk(qb), atol=1e-9)


def test_cross_check_against_ur_analytic_ik(robot: RobotModel) -> None:
    """Same forward kinematics as Universal Robots' DH (ur-analytic-ik), and the same IK solutions."""
    ua = pytest.importorskip("ur_analytic_ik")
    other = getattr(ua, robot.name)
    arm = _arm(robot)
    base = np.diag([-1.0, -1.0, 1.0, 1.0])              # example-robot-data base_link = UR base turned by pi
    rng = np.random.default_rng(40)
    q = rng.uniform(-np.pi, np.pi, (300, 6))
    theirs = np.array([other.forward_kinematics(*qi) for qi in q])
    theirs[:, :3, 3] *= 1000.0
    ours = arm.fk_flange(q)
    np.testing.assert_allclose(ours, base @ theirs, atol=1e-7)        # mm; their DH is in metres
    qb, reach, sing = arm.ik_branches_cols(pose_cols(ours, np.linalg.inv(arm.flange_T)))
    for i in np.flatnonzero(~sing.any(axis=1)):
        T = theirs[i].copy()
        T[:3, 3] /= 1000.0
        b = np.array(other.inverse_kinematics(T))
        a = qb[i, reach[i]]
        assert len(a) == len(b) == 8
        d = a[:, None, :] - b[None, :, :]
        d -= 2.0 * np.pi * np.rint(d / (2.0 * np.pi))
        dist = np.max(np.abs(d), axis=2)
        assert dist.min(axis=1).max() < 1e-6 and dist.min(axis=0).max() < 1e-6    # same sets
