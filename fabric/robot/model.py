"""The robot model: a URDF arm plus the extruder tool, in mm at the API and metres inside Pinocchio.

A :class:`RobotModel` is built from our IRB 140 URDF (or any URDF) or from any
example-robot-data robot by name. The extruder tool is added to the robot's
URDF as three links hanging from the flange: ``tool_body`` (a cylinder along
the flange z axis), ``tool_nozzle`` (a thin cylinder ending just short of the
tip, so a nozzle printing a first layer does not count as touching the plate)
and ``tcp`` (the nozzle tip; its +z points out of the nozzle). The combined
URDF is what Pinocchio loads, so :meth:`RobotModel.urdf_text` re-exports
exactly the model in use.

Kinematics: the arm's IK family is detected from its URDF at load time
(``ik_family.py``: OPW arms such as the IRB 140 and the KUKA KR6 R700,
UR-type arms, and 7-axis Panda-type arms; each derived model checked against
Pinocchio). For a closed-form family FK and IK are its vectorised closed form;
the Panda type's redundancy parameter (A7) is held at the cell's home value
(:meth:`RobotModel.set_posture`; ``panda.py`` says why that loses nothing for
printing). Any other arm of revolute joints (a 7-axis arm of no family) gets
the batched damped least squares of ``batch_dls.py`` (FK and IK on every
target at once, the redundancy fixed by holding one joint at the cell's home);
an arm with other joints gets the per-target Pinocchio solver of
``numeric.py``. The solvers share one interface (``solve(T_tcp_mm, q_seed) ->
(q, status)``) and the status codes of ``kinematics.py``;
:attr:`RobotModel.solver` is the one in use, :attr:`RobotModel.ik_family`
names the family.

Acceleration and jerk limits are not published for the IRB 140 (nor in URDFs):
they default to ``ACC_PER_S`` = 4 x the velocity limit per second (a joint
reaches full speed in 0.25 s) and ``JERK_PER_S2`` = 40 x per second squared
(full acceleration in 0.1 s), and can be overridden per cell.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin

from fabric.robot import frames
from fabric.robot.batch_dls import BatchDLSIK
from fabric.robot.chain_point import ChainPoint
from fabric.robot.closed_form import ClosedFormIK
from fabric.robot.ik_family import FamilyChoice, detect_ik_family
from fabric.robot.joint_axes import joint_axes
from fabric.robot.numeric import NumericIK
from fabric.robot.tool import TAPER_LINK, TAPER_STEPS, ToolGeometry
from fabric.wire.errors import ConfigError, NotFound, ValidationError

__all__ = ["RobotModel", "ToolGeometry", "DEFAULT_TOOL_T", "ACC_PER_S", "JERK_PER_S2", "IRB140_URDF"]

ACC_PER_S = 4.0
JERK_PER_S2 = 40.0
IRB140_URDF = Path(__file__).with_name("urdf") / "irb140.urdf"
DEFAULT_TOOL_T = frames.xyzrpy_to_T([0.0, 0.0, 150.0], [0.0, 0.0, 0.0])
"""Flange -> TCP of the default extruder: nozzle tip 150 mm out along the flange z axis."""


def _f(v: float) -> str:
    return f"{float(v):.12g}"


def _arm_urdf(robot_urdf: str, flange_frame: str) -> str:
    """The robot URDF cut to the arm: the chain from the root to ``flange_frame``.

    Whatever hangs below the flange (a gripper: the Panda's hand and its two
    finger joints) is dropped, links and joints, because the extruder takes
    its place; a movable joint anywhere else off the chain is made fixed, so
    the printing robot's joints are exactly the arm's. A URDF that is only an
    arm comes back unchanged.
    """
    try:
        root = ET.fromstring(robot_urdf)
    except ET.ParseError as exc:
        raise ConfigError(f"robot URDF is not valid XML: {exc}", field="robot.urdf") from exc
    joints = root.findall("joint")
    parent_of: dict[str, ET.Element] = {}
    for j in joints:
        child = j.find("child")
        if child is not None and child.get("link"):
            parent_of[str(child.get("link"))] = j
    chain: set[str] = set()
    link: str | None = flange_frame
    while link is not None and link in parent_of:
        j = parent_of[link]
        chain.add(str(j.get("name")))
        par = j.find("parent")
        link = None if par is None else par.get("link")
    below: set[str] = set()
    frontier = [flange_frame]
    while frontier:
        cur = frontier.pop()
        for j in joints:
            par, child = j.find("parent"), j.find("child")
            if par is not None and child is not None and par.get("link") == cur:
                below.add(str(child.get("link")))
                frontier.append(str(child.get("link")))
    changed = False
    for j in joints:
        child = j.find("child")
        if child is not None and child.get("link") in below:
            root.remove(j)
            changed = True
        elif j.get("type") not in ("fixed", None) and j.get("name") not in chain:
            j.set("type", "fixed")
            for tag in ("limit", "mimic", "axis", "dynamics", "safety_controller"):
                for el in j.findall(tag):
                    j.remove(el)
            changed = True
    for el in root.findall("link"):
        if el.get("name") in below:
            root.remove(el)
            changed = True
    for el in root.findall("transmission"):         # transmissions of dropped joints would name nothing
        names = {str(jt.get("name")) for jt in el.findall("joint")}
        if names and not names & chain:
            root.remove(el)
            changed = True
    return ET.tostring(root, encoding="unicode") if changed else robot_urdf


def _tool_urdf(robot_urdf: str, flange_frame: str, tool_T: np.ndarray, tool: ToolGeometry) -> str:
    """The robot URDF with the tool links (metres) hung from ``flange_frame``."""
    try:
        root = ET.fromstring(robot_urdf)
    except ET.ParseError as exc:
        raise ConfigError(f"robot URDF is not valid XML: {exc}", field="robot.urdf") from exc
    links = {el.get("name") for el in root.findall("link")}
    if flange_frame not in links:
        raise ConfigError(f"flange frame {flange_frame!r} is not a link of the URDF",
                          field="robot.flange_frame", value=flange_frame, links=sorted(links))
    for name in ("tool_body", "tool_nozzle", "tcp", *(f"{TAPER_LINK}{k + 1}" for k in range(TAPER_STEPS))):
        if name in links:
            raise ConfigError(f"URDF already has a link named {name!r}", field="robot.urdf", link=name)
    xyz_mm, rpy_deg = frames.T_to_xyzrpy(tool_T)
    tcp_xyz = " ".join(_f(v / 1000.0 + 0.0) for v in xyz_mm)
    tcp_rpy = " ".join(_f(v + 0.0) for v in np.radians(rpy_deg))
    m = 1e-3
    nz = -(tool.nozzle_clearance_mm + tool.taper_length_mm + tool.nozzle_length_mm / 2.0) * m
    taper = "".join(f"""
  <link name="{TAPER_LINK}{k + 1}"><collision><origin xyz="0 0 {_f(-(start + length / 2.0) * m)}" rpy="0 0 0"/>
    <geometry><cylinder radius="{_f(radius * m)}" length="{_f(length * m)}"/></geometry>
  </collision></link>
  <joint name="tcp-{TAPER_LINK}{k + 1}" type="fixed"><parent link="tcp"/><child link="{TAPER_LINK}{k + 1}"/>
    <origin xyz="0 0 0" rpy="0 0 0"/></joint>""" for k, (radius, length, start) in enumerate(tool.taper_steps()))
    extra = f"""
  <link name="tool_body"><collision><origin xyz="0 0 {_f(tool.body_length_mm * m / 2)}" rpy="0 0 0"/>
    <geometry><cylinder radius="{_f(tool.body_diameter_mm * m / 2)}" length="{_f(tool.body_length_mm * m)}"/></geometry>
  </collision></link>
  <joint name="flange-tool_body" type="fixed"><parent link="{flange_frame}"/><child link="tool_body"/>
    <origin xyz="0 0 0" rpy="0 0 0"/></joint>
  <link name="tcp"/>
  <joint name="flange-tcp" type="fixed"><parent link="{flange_frame}"/><child link="tcp"/>
    <origin xyz="{tcp_xyz}" rpy="{tcp_rpy}"/></joint>
  <link name="tool_nozzle"><collision><origin xyz="0 0 {_f(nz)}" rpy="0 0 0"/>
    <geometry><cylinder radius="{_f(tool.nozzle_diameter_mm * m / 2)}"
                        length="{_f(tool.nozzle_length_mm * m)}"/></geometry>
  </collision></link>
  <joint name="tcp-tool_nozzle" type="fixed"><parent link="tcp"/><child link="tool_nozzle"/>
    <origin xyz="0 0 0" rpy="0 0 0"/></joint>{taper}
"""
    for el in ET.fromstring(f"<x>{extra}</x>"):
        root.append(el)
    ET.indent(root, space="  ")
    return ('<?xml version="1.0"?>\n<!-- generated by am-fabric: robot + extruder tool, TCP link "tcp" -->\n'
            + ET.tostring(root, encoding="unicode") + "\n")


def _default_flange(urdf_text: str) -> str:
    """The usual flange link names (``tool0``, ``flange``, ``ee_link``, ``*_hand``), else the child of the
    last revolute joint."""
    root = ET.fromstring(urdf_text)
    links = [str(el.get("name")) for el in root.findall("link")]
    for name in ("tool0", "flange", "ee_link"):
        if name in links:
            return name
    hands = [n for n in links if n.endswith("_hand")]
    if hands:
        return hands[0]
    revolute = [j for j in root.findall("joint") if j.get("type") in ("revolute", "continuous")]
    if not revolute:
        raise ConfigError("URDF has no revolute joint to find a flange after", field="robot.flange_frame")
    child = revolute[-1].find("child")
    link = child.get("link") if child is not None else None
    if link is None:
        raise ConfigError(f"URDF joint {revolute[-1].get('name')!r} names no child link", field="robot.flange_frame")
    return link


class RobotModel:
    """A 6-axis (or any serial) arm with the extruder tool: kinematics and limits in mm / rad.

    Not thread-safe: ``pin_data`` is shared; give each thread its own model.
    """

    def __init__(self, urdf_text: str, tool_T: np.ndarray, flange_frame: str, name: str,
                 package_dirs: list[str] | None = None, tool: ToolGeometry | None = None) -> None:
        tool_T = np.asarray(tool_T, dtype=float)
        if tool_T.shape != (4, 4) or not np.allclose(tool_T[:3, :3].T @ tool_T[:3, :3], np.eye(3), atol=1e-9):
            raise ValidationError("tool_T must be a 4x4 rigid transform (mm)", field="tool_T")
        self.name = name
        self.tool = tool or ToolGeometry()
        self.tool.check()
        self.tool_T = tool_T.copy()
        self.flange_frame = flange_frame
        self.package_dirs = list(package_dirs or [])
        self._robot_urdf = _arm_urdf(urdf_text, flange_frame)
        self._urdf = _tool_urdf(self._robot_urdf, flange_frame, tool_T, self.tool)
        self.pin_model = pin.buildModelFromXML(self._urdf)
        if self.pin_model.nq != self.pin_model.nv:
            raise ConfigError(f"robot {name!r} has continuous / multi-dof joints (nq != nv)", robot=name)
        self.pin_data = self.pin_model.createData()
        self.collision_model = pin.buildGeomFromUrdfString(
            self.pin_model, self._urdf, pin.GeometryType.COLLISION, package_dirs=self.package_dirs)
        self._add_collision_pairs()
        self.nq: int = int(self.pin_model.nq)
        self.joint_names: list[str] = [str(n) for n in self.pin_model.names[1:]]
        self.tcp_frame_id = int(self.pin_model.getFrameId("tcp"))
        self.flange_frame_id = int(self.pin_model.getFrameId(flange_frame))
        self.lower_rad = np.array(self.pin_model.lowerPositionLimit, dtype=float)
        self.upper_rad = np.array(self.pin_model.upperPositionLimit, dtype=float)
        self.vel_limit_rad_s = np.array(self.pin_model.velocityLimit, dtype=float)
        self.acc_limit_rad_s2 = ACC_PER_S * self.vel_limit_rad_s
        self.jerk_limit_rad_s3 = JERK_PER_S2 * self.vel_limit_rad_s
        self._tool_inv = frames.inv_T(self.tool_T)
        # tcp_xyz_mm's walk back from the TCP, checked against Pinocchio (None: this model has none)
        self.chain_point: ChainPoint | None = ChainPoint.of(self.pin_model, self.tcp_frame_id)
        self.family_choice: FamilyChoice = detect_ik_family(self.pin_model, self.flange_frame_id,
                                                            self.lower_rad, self.upper_rad)
        self.closed_form: ClosedFormIK | None = None
        self.solver: ClosedFormIK | BatchDLSIK | NumericIK
        self.posture_rad: np.ndarray | None = None     # where a redundant arm's free parameter is pulled to
        self.hold_joint: int | None = None             # the joint a redundant arm's IK holds at the posture
        arm = self.family_choice.arm
        if arm is not None and arm.free_joint is not None:     # a closed form's parameter joint: held by default
            self.hold_joint = arm.free_joint
        self._build_solver()

    # Construction ------------------------------------------------------
    @classmethod
    def from_urdf(cls, path_or_text: str | Path, tool_T: np.ndarray = DEFAULT_TOOL_T,
                  flange_frame: str = "flange", name: str = "irb140",
                  tool: ToolGeometry | None = None) -> RobotModel:
        """Load a URDF file (or URDF text); meshes resolve relative to the file's directory."""
        text = str(path_or_text)
        package_dirs: list[str] = []
        if not text.lstrip().startswith("<"):
            path = Path(text)
            if not path.is_file():
                raise NotFound(f"URDF file not found: {path}", file=str(path))
            text = path.read_text()
            package_dirs = [str(path.parent.resolve())]
        return cls(text, tool_T, flange_frame, name, package_dirs, tool)

    @classmethod
    def from_example_robot_data(cls, name: str, tool_T: np.ndarray = DEFAULT_TOOL_T,
                                flange_frame: str | None = None,
                                tool: ToolGeometry | None = None) -> RobotModel:
        """Any arm of example-robot-data by loader name (``"ur5"``, ``"panda"``, ...).

        ``flange_frame`` defaults to the URDF's ``tool0`` / ``flange`` / ``ee_link`` /
        ``*_hand`` link, else the child of the last revolute joint. Robots with
        continuous (unbounded) joints are refused (their nq != nv).
        """
        from example_robot_data.robots_loader import ROBOTS
        if name not in ROBOTS:
            raise NotFound(f"unknown example-robot-data robot {name!r}", robot=name)
        loader = ROBOTS[name]()
        urdf_path = Path(loader.df_path)
        text = urdf_path.read_text()
        share = Path(loader.model_path).resolve().parent.parent   # .../share, holding example-robot-data/
        if flange_frame is None:
            flange_frame = _default_flange(text)
        return cls(text, tool_T, flange_frame, name, [str(share)], tool)

    def with_limits(self, lower_rad: np.ndarray | None = None, upper_rad: np.ndarray | None = None,
                    vel_limit_rad_s: np.ndarray | None = None, acc_limit_rad_s2: np.ndarray | None = None,
                    jerk_limit_rad_s3: np.ndarray | None = None) -> RobotModel:
        """Override limits in place (cell ``[limits]``); position limits may only narrow the URDF's."""
        for attr, val in (("lower_rad", lower_rad), ("upper_rad", upper_rad), ("vel_limit_rad_s", vel_limit_rad_s),
                          ("acc_limit_rad_s2", acc_limit_rad_s2), ("jerk_limit_rad_s3", jerk_limit_rad_s3)):
            if val is None:
                continue
            arr = np.asarray(val, dtype=float)
            if arr.shape != (self.nq,) or not np.all(np.isfinite(arr)):
                raise ValidationError(f"{attr} needs {self.nq} finite values", field=attr)
            setattr(self, attr, arr.copy())
        if np.any(self.lower_rad >= self.upper_rad):
            j = int(np.argmax(self.lower_rad >= self.upper_rad))
            raise ValidationError(f"joint {self.joint_names[j]}: lower limit >= upper limit",
                                  field="limits", joint=self.joint_names[j])
        for attr in ("vel_limit_rad_s", "acc_limit_rad_s2", "jerk_limit_rad_s3"):
            if np.any(getattr(self, attr) <= 0):
                raise ValidationError(f"{attr} must be > 0", field=attr)
        self._build_solver()
        return self

    # Kinematics --------------------------------------------------------
    def fk(self, q: np.ndarray) -> np.ndarray:
        """TCP pose(s) in the robot base frame, mm: (4, 4) for q (nq,), (N, 4, 4) for (N, nq)."""
        return self.fk_flange(q) @ self.tool_T

    def tcp_xyz_mm(self, q: np.ndarray) -> np.ndarray:
        """TCP positions (N, 3) in the robot base frame, mm, for joints (N, nq): :meth:`fk`'s, faster where the
        arm's family computes a point without the whole pose (OPW arms), or the chain of joints can be walked back
        from the TCP (``chain_point.py``: UR, Panda)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        arm = getattr(self.closed_form, "arm", None)
        if arm is not None and hasattr(arm, "point_xyz"):
            return arm.point_xyz(q, self.tool_T[:3, 3])
        if self.chain_point is not None:
            return self.chain_point(q)
        return self.fk(q)[:, :3, 3]

    def fk_flange(self, q: np.ndarray) -> np.ndarray:
        """Flange pose(s) in the robot base frame, mm (same shapes as :meth:`fk`)."""
        q = np.asarray(q, dtype=float)
        if q.shape[-1] != self.nq:
            raise ValidationError(f"q needs {self.nq} joints, got shape {q.shape}", field="q")
        if self.closed_form is not None:
            return self.closed_form.fk_flange(q)
        if isinstance(self.solver, BatchDLSIK):           # its vectorised product of exponentials
            T = self.solver.fk(q.reshape(-1, self.nq)) @ self._tool_inv
            return T[0] if q.ndim == 1 else T.reshape(*q.shape[:-1], 4, 4)
        return self.frame_poses(q, self.flange_frame_id)

    def frame_poses(self, q: np.ndarray, frame_id: int) -> np.ndarray:
        """Pose(s) of any Pinocchio frame (mm), by a Pinocchio loop over rows."""
        qs = np.atleast_2d(np.asarray(q, dtype=float))
        out = np.empty((len(qs), 4, 4))
        for i, qi in enumerate(qs):
            pin.forwardKinematics(self.pin_model, self.pin_data, qi)
            out[i] = pin.updateFramePlacement(self.pin_model, self.pin_data, frame_id).homogeneous
        out[:, :3, 3] *= 1000.0
        return out[0] if np.asarray(q).ndim == 1 else out

    def ik(self, T: np.ndarray, q_seed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Joints (N, nq) and status (N,) uint8 reaching TCP poses T ((4, 4) or (N, 4, 4), mm, base frame).

        Row i is solved continuous with row i-1 (row 0 with ``q_seed``): the
        valid solution nearest the previous one. Status codes: ``IK_*`` of
        ``fabric.robot.kinematics``.
        """
        T = np.asarray(T, dtype=float).reshape(-1, 4, 4)
        q_seed = np.asarray(q_seed, dtype=float).reshape(-1)
        if q_seed.shape != (self.nq,):
            raise ValidationError(f"q_seed needs {self.nq} joints", field="q_seed")
        return self.solver.solve(T, q_seed)

    def within_limits(self, q: np.ndarray, tol_rad: float = 1e-9) -> np.ndarray:
        """Rows of q (N, nq) inside the position limits: bool (N,)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        return np.all((q >= self.lower_rad - tol_rad) & (q <= self.upper_rad + tol_rad), axis=1)

    # URDF --------------------------------------------------------------
    def urdf_text(self) -> str:
        """The robot and tool as one URDF (metres), with the TCP link ``tcp``."""
        return self._urdf

    def export_urdf(self, path: str | Path) -> None:
        """Write :meth:`urdf_text` to ``path``."""
        Path(path).write_text(self._urdf)

    # Internals ---------------------------------------------------------
    @property
    def ik_family(self) -> str:
        """The IK family detected from the URDF: ``"opw"``, ``"ur"``, ``"panda"`` or ``"numeric"``."""
        return self.family_choice.family

    def _build_solver(self) -> None:
        """The IK solver for the current limits: the detected family's closed form, else numeric."""
        arm = self.family_choice.arm
        if arm is not None:
            free = None if self.posture_rad is None or arm.free_joint is None else self.posture_rad[arm.free_joint]
            self.closed_form = ClosedFormIK(arm, self.lower_rad, self.upper_rad, self.tool_T, free)
            self.solver = self.closed_form
        else:
            self.closed_form = None
            axes = joint_axes(self.pin_model, self.flange_frame_id)
            if axes.revolute.all():             # any revolute arm of no family (7 axes): batched DLS on all rows
                self.solver = BatchDLSIK(axes, self.lower_rad, self.upper_rad, self.tool_T, self.posture_rad,
                                         self.hold_joint)
            else:
                self.solver = NumericIK(self.pin_model, self.lower_rad, self.upper_rad, self.tcp_frame_id)

    def set_posture(self, q_rad: np.ndarray, hold_joint: str | None = None) -> None:
        """The posture a redundant arm's IK resolves its free parameter towards (a cell's home), and the
        joint it holds there.

        A closed form with a parameter joint (the Panda type's A7) holds that joint at its posture value;
        ``hold_joint``, if given, must name it. The batched DLS of an arm of no family holds ``hold_joint``
        (``batch_dls.py``). No effect on a 6-axis closed form.
        """
        q = np.asarray(q_rad, dtype=float).reshape(-1)
        if q.shape != (self.nq,):
            raise ValidationError(f"posture needs {self.nq} joints", field="posture")
        if hold_joint is not None and hold_joint not in self.joint_names:
            raise ConfigError(f"{hold_joint!r} is not a joint of {self.name}", field="robot.redundancy_joint",
                              value=hold_joint, joints=self.joint_names)
        free = None if self.closed_form is None else self.closed_form.free_joint
        if free is not None and hold_joint is not None and self.joint_names.index(hold_joint) != free:
            raise ConfigError(f"the {self.ik_family} closed form takes {self.joint_names[free]} as its redundancy "
                              f"parameter, not {hold_joint}", field="robot.redundancy_joint", value=hold_joint,
                              expected=self.joint_names[free])
        self.posture_rad = q.copy()
        if free is not None:
            self.hold_joint = free
        else:
            self.hold_joint = None if hold_joint is None else self.joint_names.index(hold_joint)
        if isinstance(self.solver, BatchDLSIK) or free is not None:
            self._build_solver()

    def _add_collision_pairs(self) -> None:
        """All pairs of geometries except those on the same or on parent/child joints."""
        gm, model = self.collision_model, self.pin_model
        objs = gm.geometryObjects
        for a in range(len(objs)):
            for b in range(a + 1, len(objs)):
                ja, jb = objs[a].parentJoint, objs[b].parentJoint
                if ja == jb or model.parents[ja] == jb or model.parents[jb] == ja:
                    continue
                gm.addCollisionPair(pin.CollisionPair(a, b))
