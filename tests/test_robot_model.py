"""The IRB 140 model against its published figures, and the RobotModel API (mm at the API, metres inside)."""
from __future__ import annotations

import itertools

import numpy as np
import pinocchio as pin
import pytest

from fabric.robot import frames
from fabric.robot.kinematics import IRB140_ARM
from fabric.robot.model import ACC_PER_S, IRB140_URDF, JERK_PER_S2, RobotModel, ToolGeometry
from fabric.wire.errors import ConfigError, NotFound, ValidationError

ABB_RANGES_DEG = [(-180, 180), (-90, 110), (-230, 50), (-200, 200), (-115, 115), (-400, 400)]
ABB_SPEEDS_DEG_S = [200, 200, 260, 360, 360, 450]


@pytest.fixture(scope="module")
def robot() -> RobotModel:
    return RobotModel.from_urdf(IRB140_URDF)


def _pin_frame_mm(robot: RobotModel, q: np.ndarray, name: str) -> np.ndarray:
    """Pose of a frame straight from Pinocchio on the URDF (no fabric code in the path), mm."""
    model = pin.buildModelFromXML(IRB140_URDF.read_text())
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    T = data.oMf[model.getFrameId(name)].homogeneous.copy()
    T[:3, 3] *= 1000.0
    return T


def test_flange_at_zero_matches_published_figure(robot: RobotModel) -> None:
    for T in (IRB140_ARM.fk_flange(np.zeros(6)), robot.fk_flange(np.zeros(6)),
              _pin_frame_mm(robot, np.zeros(6), "flange")):
        np.testing.assert_allclose(T[:3, 3], [515.0, 0.0, 712.0], atol=1e-9)
        np.testing.assert_allclose(T[:3, 2], [1.0, 0.0, 0.0], atol=1e-12)   # flange z points forward


def test_closed_form_fk_equals_pinocchio_on_the_urdf(robot: RobotModel) -> None:
    rng = np.random.default_rng(3)
    q = rng.uniform(robot.lower_rad, robot.upper_rad, (50, 6))
    ours = robot.fk(q)
    for i in range(0, 50, 7):
        ref = _pin_frame_mm(robot, q[i], "flange") @ robot.tool_T
        np.testing.assert_allclose(ours[i], ref, atol=1e-9)
    np.testing.assert_allclose(robot.frame_poses(q[:5], robot.tcp_frame_id), ours[:5], atol=1e-9)


def test_reach_is_810_mm(robot: RobotModel) -> None:
    # ABB's reach is the wrist centre's largest distance from the A1 axis: a1 + a2 + d4
    rng = np.random.default_rng(4)
    q = rng.uniform(robot.lower_rad, robot.upper_rad, (200_000, 6))
    T = robot.fk_flange(q)
    wc = T[:, :3, 3] - 65.0 * T[:, :3, 2]
    rho = np.hypot(wc[:, 0], wc[:, 1])
    assert 800.0 < rho.max() <= 810.0 + 1e-9
    stretched = robot.fk_flange(np.radians([0, 90, -90, 0, 0, 0]))
    assert stretched[0, 3] == pytest.approx(810.0 + 65.0, abs=1e-9)     # wrist centre at 810, flange d6 beyond


def test_limits_and_speeds_are_the_abb_figures(robot: RobotModel) -> None:
    np.testing.assert_allclose(np.degrees(robot.lower_rad), [lo for lo, _ in ABB_RANGES_DEG], atol=1e-9)
    np.testing.assert_allclose(np.degrees(robot.upper_rad), [hi for _, hi in ABB_RANGES_DEG], atol=1e-9)
    np.testing.assert_allclose(np.degrees(robot.vel_limit_rad_s), ABB_SPEEDS_DEG_S, atol=1e-9)
    np.testing.assert_allclose(robot.acc_limit_rad_s2, ACC_PER_S * robot.vel_limit_rad_s)
    np.testing.assert_allclose(robot.jerk_limit_rad_s3, JERK_PER_S2 * robot.vel_limit_rad_s)
    assert robot.joint_names == [f"joint_{i}" for i in range(1, 7)] and robot.nq == 6


def test_axis_directions_follow_abb(robot: RobotModel) -> None:
    base = robot.fk_flange(np.zeros(6))[:3, 3]
    fwd = robot.fk_flange(np.radians([0, 10, 0, 0, 0, 0]))[:3, 3]
    down = robot.fk_flange(np.radians([0, 0, 10, 0, 0, 0]))[:3, 3]
    ccw = robot.fk_flange(np.radians([10, 0, 0, 0, 0, 0]))[:3, 3]
    assert fwd[0] > base[0] + 50          # A2 + tilts the upper arm forward
    assert down[2] < base[2] - 50         # A3 + tilts the forearm down (ABB sign)
    assert ccw[1] > 50                    # A1 + turns counter-clockwise seen from above
    pointing_down = robot.fk_flange(np.radians([0, 0, 0, 0, 90, 0]))
    np.testing.assert_allclose(pointing_down[:3, 2], [0, 0, -1], atol=1e-12)   # A5 = 90: flange down
    np.testing.assert_allclose(frames.quat_from_R(pointing_down[:3, :3]), [0, 0, 1, 0], atol=1e-12)


def test_tool_tcp_frame_and_collision_geometry(robot: RobotModel) -> None:
    assert robot.pin_model.frames[robot.tcp_frame_id].name == "tcp"
    T = robot.fk(np.zeros(6))
    np.testing.assert_allclose(T[:3, 3], [515.0 + 150.0, 0.0, 712.0], atol=1e-9)   # nozzle 150 mm out
    names = [g.name for g in robot.collision_model.geometryObjects]
    assert any(n.startswith("tool_body") for n in names) and any(n.startswith("tool_nozzle") for n in names)
    assert sum(n.startswith("link_") for n in names) == 6
    # the nozzle cylinder (29 mm long) ends 1 mm short of the tip, on the TCP axis
    gd = robot.collision_model.createData()
    q = np.radians([0, 0, 0, 0, 90, 0])
    pin.framesForwardKinematics(robot.pin_model, robot.pin_data, q)
    pin.updateGeometryPlacements(robot.pin_model, robot.pin_data, robot.collision_model, gd)
    k = next(i for i, n in enumerate(names) if n.startswith("tool_nozzle"))
    centre_mm = gd.oMg[k].translation * 1000.0
    np.testing.assert_allclose(centre_mm, robot.fk(q)[:3, 3] + [0.0, 0.0, 1.0 + 29.0 / 2], atol=1e-9)
    # no self-collision in the nozzle-down home pose
    assert not pin.computeCollisions(robot.pin_model, robot.pin_data, robot.collision_model, gd, q, True)


def test_vectorised_and_single_shapes(robot: RobotModel) -> None:
    q = np.zeros((4, 6))
    assert robot.fk(q).shape == (4, 4, 4) and robot.fk(q[0]).shape == (4, 4)
    qs, st = robot.ik(robot.fk(q[0]), q[0])
    assert qs.shape == (1, 6) and st.shape == (1,) and st.dtype == np.uint8
    assert robot.within_limits(np.array([[0, 0, 0, 0, 2.1, 0], [0] * 6])).tolist() == [False, True]


def test_bad_inputs_are_typed_errors(robot: RobotModel) -> None:
    with pytest.raises(ValidationError):
        robot.fk(np.zeros(5))
    with pytest.raises(ConfigError) as exc:
        RobotModel.from_urdf(IRB140_URDF, flange_frame="tool9")
    assert exc.value.details["field"] == "robot.flange_frame"
    with pytest.raises(NotFound):
        RobotModel.from_urdf("/nonexistent/robot.urdf")
    with pytest.raises(ConfigError):
        RobotModel.from_urdf(IRB140_URDF, tool=ToolGeometry(body_length_mm=0.0))
    with pytest.raises(ValidationError):
        RobotModel.from_urdf(IRB140_URDF).with_limits(lower_rad=np.full(6, 1.0), upper_rad=np.full(6, 0.5))


def test_tool_offset_and_rotation_are_honoured() -> None:
    tool_T = frames.xyzrpy_to_T([10.0, -5.0, 120.0], [0.0, 20.0, 30.0])
    r = RobotModel.from_urdf(IRB140_URDF, tool_T=tool_T)
    q = np.radians([10, 20, -30, 40, 50, 60])
    np.testing.assert_allclose(r.fk(q), r.fk_flange(q) @ tool_T, atol=1e-9)
    np.testing.assert_allclose(r.frame_poses(q, r.tcp_frame_id), r.fk(q), atol=1e-9)
    qi, st = r.ik(r.fk(q), q)
    assert st[0] == 0
    np.testing.assert_allclose(qi[0], q, atol=1e-9)


def test_frame_helpers_round_trip() -> None:
    rng = np.random.default_rng(5)
    rpy = rng.uniform(-np.pi, np.pi, (500, 3)) * np.array([1.0, 0.49, 1.0])
    R = frames.rpy_to_R(rpy)
    np.testing.assert_allclose(frames.R_to_rpy(R), rpy, atol=1e-10)
    q = frames.quat_from_R(R)
    assert np.all(q[:, 0] >= 0) and np.allclose(np.linalg.norm(q, axis=1), 1.0)
    # a half turn (w = 0 but for rounding, of either sign): the first of x, y, z that is not zero is positive,
    # whatever sign rounding gave w (frames.quat_sign)
    for w in (1e-17, -1e-17, 0.0, -0.0):
        for xyz in ((0.6, -0.8, 0.0), (-0.6, 0.8, 0.0), (1e-12, -1.0, 0.0), (0.0, 0.0, -1.0)):
            got = frames.quat_sign(np.array([w, *xyz]))
            lead = next(v for v in got[1:] if abs(v) > frames.QUAT_SIGN_TOL)
            assert lead > 0 and np.allclose(np.abs(got), np.abs([w, *xyz]))
    np.testing.assert_allclose(frames.R_from_quat(q), R, atol=1e-12)
    for Rs in (np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])):  # 180 deg turns
        np.testing.assert_allclose(frames.R_from_quat(frames.quat_from_R(Rs)), Rs, atol=1e-12)
    T = frames.xyzrpy_to_T(rng.normal(size=(500, 3)) * 100, np.degrees(rpy))
    np.testing.assert_allclose(frames.inv_T(T) @ T, np.broadcast_to(np.eye(4), T.shape), atol=1e-12)
    assert frames.frame_from_z_axis(np.zeros((0, 3)), np.array([1.0, 0.0, 0.0])).shape == (0, 3, 3)
    Rz = frames.frame_from_z_axis(np.array([0.0, 0.0, -1.0]), np.array([[0.0, 0.0, 1.0], [2.0, 1.0, 5.0]]))
    np.testing.assert_allclose(Rz[:, :, 2], [[0, 0, -1], [0, 0, -1]], atol=1e-12)   # x_ref parallel: fallback
    np.testing.assert_allclose(Rz[1, :, 0], np.array([2.0, 1.0, 0.0]) / np.sqrt(5.0), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(Rz), 1.0)
    np.testing.assert_allclose(frames.rot_about_z(R, 0.3), R @ frames.rot_z(0.3), atol=1e-12)


def test_two_ik_solvers_one_interface(robot: RobotModel) -> None:
    """The numeric solver needs only the Pinocchio model, limits and TCP frame; it agrees with the closed form."""
    from fabric.robot.closed_form import ClosedFormIK
    from fabric.robot.kinematics import IK_JOINT_LIMIT, IK_OK, IK_OUT_OF_REACH
    from fabric.robot.numeric import NumericIK
    assert isinstance(robot.solver, ClosedFormIK) and robot.solver is robot.closed_form
    numeric = NumericIK(robot.pin_model, robot.lower_rad, robot.upper_rad, robot.tcp_frame_id)
    q = np.radians([[10, 20, -30, 40, 50, 60], [12, 22, -28, 38, 52, 58]])
    T = robot.fk(q)
    q_cf, st_cf = robot.solver.solve(T, q[0])
    q_num, st_num = numeric.solve(T, q[0])
    assert st_cf.tolist() == st_num.tolist() == [IK_OK, IK_OK]
    np.testing.assert_allclose(q_num, q_cf, atol=1e-6)
    far = T[:1].copy()
    far[0, :3, 3] = [3000.0, 0.0, 500.0]
    assert numeric.solve(far, q[0])[1].tolist() == [IK_OUT_OF_REACH]
    a5 = np.arange(6) == 4                                  # |A5| <= 0.5 rad: both wrists (+-50 deg) are beyond it
    narrow = NumericIK(robot.pin_model, np.where(a5, -0.5, robot.lower_rad), np.where(a5, 0.5, robot.upper_rad),
                       robot.tcp_frame_id)
    assert narrow.solve(T[:1], q[0])[1].tolist() == [IK_JOINT_LIMIT]


def test_limits_change_rebuilds_the_numeric_solver() -> None:
    text = IRB140_URDF.read_text().replace('<origin xyz="0.380 0 0" rpy="0 0 0"/><axis xyz="0 1 0"/>',
                                           '<origin xyz="0.380 0.02 0" rpy="0 0 0"/><axis xyz="0 1 0"/>')
    r = RobotModel.from_urdf(text)                           # an offset wrist: no closed-form family
    from fabric.robot.batch_dls import BatchDLSIK
    assert isinstance(r.solver, BatchDLSIK) and r.closed_form is None and r.ik_family == "numeric"
    upper = r.upper_rad.copy()
    upper[0] = 0.5
    r.with_limits(upper_rad=upper)
    np.testing.assert_allclose(r.solver.upper_rad, upper)


def test_the_panda_has_seven_joints_and_a_closed_form() -> None:
    r = RobotModel.from_example_robot_data("panda")          # 7 axes (fingers dropped): the Panda-type family
    assert r.ik_family == "panda" and r.closed_form is r.solver and r.closed_form is not None
    assert r.family_choice.refused["opw"] == "needs 6 joints, the URDF has 7"
    assert r.joint_names == [f"panda_joint{j}" for j in range(1, 8)] and r.closed_form.nq == 7


def test_limits_change_rebuilds_the_closed_form_solver() -> None:
    r = RobotModel.from_example_robot_data("ur5")
    from fabric.robot.closed_form import ClosedFormIK
    assert isinstance(r.solver, ClosedFormIK) and r.ik_family == "ur"
    upper = r.upper_rad.copy()
    upper[0] = 0.5
    r.with_limits(upper_rad=upper)
    assert r.solver is r.closed_form and r.closed_form is not None
    np.testing.assert_allclose(r.closed_form.upper_rad, upper)


def test_a_tapered_nozzle_is_its_tip_a_cone_of_steps_and_its_shank() -> None:
    """The multi-axis cell's nozzle: a 0.7 mm flat for 1 mm, a cone to 2 mm over 3 mm, then the 2 mm shank. The
    cone's steps are as wide as the cone at their tops (nothing of it outside them) and stand end to end
    between the tip and the shank; the certified sweep's exempt tip is the flat's radius."""
    from fabric.collision.bodies import RobotBodies
    from fabric.robot.cell import Cell
    cell = Cell.builtin("irb140-multiaxis")
    tool = cell.robot.tool
    assert (tool.tip_diameter_mm, tool.taper_length_mm, tool.tip_mm) == (0.7, 3.0, 0.7)
    steps = tool.taper_steps()
    np.testing.assert_allclose([r for r, _l, _s in steps], [0.35 + 0.65 / 3, 0.35 + 1.3 / 3, 1.0])
    ends = [(start, start + length) for _r, length, start in steps]
    assert ends[0][0] == 1.0 and ends[-1][1] == pytest.approx(4.0)
    assert all(a[1] == pytest.approx(b[0]) for a, b in itertools.pairwise(ends))
    bodies = RobotBodies(cell)
    axial = {b.name: (r, h, off) for b, r, h, off in bodies.axial_cylinders()}
    assert bodies.tip_radius_mm == 0.35 and axial["tool_tip"][0] == 0.35
    for k, (r, length, start) in enumerate(steps, 1):
        assert axial[f"tool_taper{k}"] == pytest.approx((r, length / 2, -(start + length / 2)))
    assert axial["tool_nozzle"] == pytest.approx((1.0, 14.5, -(4.0 + 14.5)))     # the shank begins where it ends
    # the untapered nozzle has no steps and its tip is as wide as it
    assert ToolGeometry().taper_steps() == [] and ToolGeometry().tip_mm == 8.0


@pytest.mark.parametrize("tip, taper", [(3.0, 3.0), (0.7, 0.0), (0.0, 3.0), (-0.7, 3.0)])
def test_a_taper_wider_than_its_nozzle_or_half_given_is_refused(tip: float, taper: float) -> None:
    with pytest.raises(ConfigError, match="tool\\.") as exc:
        RobotModel.from_urdf(IRB140_URDF, tool=ToolGeometry(nozzle_diameter_mm=2.0, tip_diameter_mm=tip,
                                                            taper_length_mm=taper))
    assert exc.value.details["field"] in ("tool.tip_diameter_mm", "tool.taper_length_mm")
