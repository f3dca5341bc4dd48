"""Which IK family an arm belongs to: OPW, UR-type, Panda-type (7 axes), or none (numeric IK), detected from its URDF.

Each closed-form family is tried in turn (``opw``, then ``ur``, then the
7-axis ``panda``): its parameters are derived from the joint axes at zero
(``opw_derive.py``, ``ur_derive.py``, ``panda_derive.py``)
and the resulting model is accepted only if its flange poses equal
Pinocchio's on random joint vectors (``FK_TOL_MM``, ``FK_TOL_ROT``). The first
family accepted wins; otherwise the arm uses numeric IK, and the reason each
family refused it is kept for ``cell show`` / ``cell list``.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np
import pinocchio as pin

from fabric.robot.arm_family import FK_TOL_MM, FK_TOL_ROT, ClosedFormArm, IKFamilyMismatch
from fabric.robot.joint_axes import JointAxes, fk_mismatch, joint_axes
from fabric.robot.opw import OPWArm
from fabric.robot.opw_derive import derive_opw
from fabric.robot.panda import PandaArm
from fabric.robot.panda_derive import derive_panda
from fabric.robot.ur import URArm
from fabric.robot.ur_derive import derive_ur

__all__ = ["FamilyChoice", "detect_ik_family", "opw_arm", "ur_arm", "panda_arm", "NUMERIC"]

NUMERIC = "numeric"
_Arm = TypeVar("_Arm", OPWArm, URArm, PandaArm)


@dataclass(frozen=True)
class FamilyChoice:
    """The detected family, its closed-form arm (None for numeric IK) and why the other families refused."""

    family: str
    arm: ClosedFormArm | None
    refused: dict[str, str] = field(default_factory=dict)

    def parameters(self) -> dict[str, float]:
        """The family's lengths (mm) and joint offsets (deg) for display; empty for numeric IK."""
        if isinstance(self.arm, (OPWArm, URArm)):
            p = self.arm.params
            out = {f"{k}_mm": round(v, 9) + 0.0 for k, v in p.lengths_mm().items()}
            out.update({f"offset{j + 1}_deg": round(float(np.degrees(o)), 9) + 0.0
                        for j, o in enumerate(p.offsets_rad)})
            out.update({f"sign{j + 1}": float(s) for j, s in enumerate(p.signs)})
            return out
        if isinstance(self.arm, PandaArm):
            pp = self.arm.params
            out = {f"{k}_mm": round(v, 9) + 0.0 for k, v in pp.lengths_mm().items()}
            out["offset2_deg"] = round(float(np.degrees(pp.offset2_rad)), 9) + 0.0
            return out
        return {}


def _verified(arm: _Arm, family: str, model: pin.Model, flange_frame_id: int,
              lower_rad: np.ndarray, upper_rad: np.ndarray) -> _Arm:
    pos, rot = fk_mismatch(model, flange_frame_id, arm.fk_flange, lower_rad, upper_rad)
    if pos > FK_TOL_MM or rot > FK_TOL_ROT:
        raise IKFamilyMismatch(family, f"the derived model's flange differs from the URDF's by {pos:.3g} mm / "
                                       f"{rot:.3g} (rotation)", pos)
    return arm


def opw_arm(model: pin.Model, flange_frame_id: int, lower_rad: np.ndarray, upper_rad: np.ndarray,
            axes: JointAxes | None = None) -> OPWArm:
    """The verified OPW arm of a Pinocchio model, or :class:`IKFamilyMismatch` saying which condition failed."""
    ax = axes or joint_axes(model, flange_frame_id)
    return _verified(OPWArm(derive_opw(ax)), "opw", model, flange_frame_id, lower_rad, upper_rad)


def ur_arm(model: pin.Model, flange_frame_id: int, lower_rad: np.ndarray, upper_rad: np.ndarray,
           axes: JointAxes | None = None) -> URArm:
    """The verified UR-type arm of a Pinocchio model, or :class:`IKFamilyMismatch`."""
    ax = axes or joint_axes(model, flange_frame_id)
    return _verified(URArm(derive_ur(ax)), "ur", model, flange_frame_id, lower_rad, upper_rad)


def panda_arm(model: pin.Model, flange_frame_id: int, lower_rad: np.ndarray, upper_rad: np.ndarray,
              axes: JointAxes | None = None) -> PandaArm:
    """The verified Panda-type arm (7 axes, A7 the parameter) of a Pinocchio model, or :class:`IKFamilyMismatch`."""
    ax = axes or joint_axes(model, flange_frame_id)
    return _verified(PandaArm(derive_panda(ax)), "panda", model, flange_frame_id, lower_rad, upper_rad)


def detect_ik_family(model: pin.Model, flange_frame_id: int, lower_rad: np.ndarray,
                     upper_rad: np.ndarray) -> FamilyChoice:
    """The first closed-form family that fits the arm exactly, else numeric IK (module docstring)."""
    ax = joint_axes(model, flange_frame_id)
    refused: dict[str, str] = {}
    builders: tuple[tuple[str, Callable[..., ClosedFormArm]], ...] = (
        ("opw", opw_arm), ("ur", ur_arm), ("panda", panda_arm))
    for family, build in builders:
        try:
            arm = build(model, flange_frame_id, lower_rad, upper_rad, ax)
        except IKFamilyMismatch as exc:
            refused[family] = str(exc.details.get("condition", exc))
            continue
        return FamilyChoice(family, arm, refused)
    return FamilyChoice(NUMERIC, None, refused)
