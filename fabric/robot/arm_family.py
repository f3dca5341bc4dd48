"""What a closed-form arm family provides to the solver, and the error raised when a URDF is not of a family.

A family (``opw.py``: parallel base axes and a spherical wrist; ``ur.py``:
three parallel axes and an offset wrist; ``panda.py``: 7 axes, a spherical
shoulder and A7 as the redundancy parameter; ``kinematics.py``: the
ABB-convention spherical-wrist arm kept as the reference of the tests) is a
class with the methods of :class:`ClosedFormArm`.
:class:`~fabric.robot.closed_form.ClosedFormIK` uses only these, so branch
choice, joint limits, continuity, multi-turn joints and the singular holds are
written once for every family.

A redundant family names the joint it takes as a parameter (``free_joint``):
every IK call gets that joint's value per row (``q_free``) and returns it
unchanged in the joints; the 6-axis families have none and ignore ``q_free``.

Poses enter the family as *columns* ``C`` (9, N): position, z axis and y axis
of the arm's **end frame** in the robot base frame (``pose_cols``). The end
frame is the family's own flange convention; ``flange_T`` maps it to the URDF
flange (``T_flange = T_end @ flange_T``), so the solver gathers end-frame
columns from TCP poses with one post-multiplication by
``inv(flange_T @ tool_T)``.

Branches are numbered ``b = 4 * shoulder + 2 * elbow + wrist`` in every family
(8 per target; per target and ``q_free`` for a redundant one).
"""
from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from fabric.wire.errors import ConfigError

__all__ = ["ClosedFormArm", "IKFamilyMismatch", "cols_in_frame", "stack_branches", "ANG_TOL", "DIST_TOL_MM",
           "FK_TOL_MM", "FK_TOL_ROT"]

ANG_TOL = 1e-7            # |cos| for "perpendicular", |sin| for "parallel" axes
DIST_TOL_MM = 1e-6        # "the axes meet"
FK_TOL_MM = 1e-6          # the derived model must reproduce Pinocchio's flange to this (position) ...
FK_TOL_ROT = 1e-9         # ... and this (rotation matrix entries)


class IKFamilyMismatch(ConfigError):
    """A URDF is not of the closed-form family it was given to.

    ``details``: ``family`` ("opw", "ur", "panda"), ``condition`` (the first condition
    that failed, in words) and, where measured, ``value`` (the number that broke it).
    """

    def __init__(self, family: str, condition: str, value: float | None = None, **details: Any) -> None:
        shown = "" if value is None else f" ({value:.6g})"
        article = "an" if family.upper()[0] in "AEFHILMNORSX" else "a"
        super().__init__(f"not {article} {family.upper()}-type arm: {condition}{shown}", family=family,
                         condition=condition, value=value, **details)


class ClosedFormArm(Protocol):
    """The closed-form kinematics of one arm: all 8 IK branches of end-frame columns, vectorised.

    Joints are ``nq`` per row (6; 7 for a redundant family, whose ``free_joint`` is given).
    """

    family: str                 # "opw", "ur", "panda", ...
    flange_T: np.ndarray        # end frame -> URDF flange (4, 4) mm
    nq: int                     # joints of the arm

    @property
    def free_joint(self) -> int | None:
        """The joint a redundant family takes as an input of every IK call (``q_free``); None for 6 axes."""
        ...

    def fk_flange(self, q_rad: np.ndarray) -> np.ndarray:
        """URDF flange poses (N, 4, 4) mm for joints (N, nq); (4, 4) for (nq,)."""
        ...

    def q1_free(self, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A1 of branch 0 per row (N,) and the rows where it is undefined (N,) bool (held by the solver)."""
        ...

    def ik_branches_cols(self, C: np.ndarray, q1_hold: np.ndarray | None = None,
                         q_free: float | np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All 8 branches: ``q`` (N, 8, nq) in [-pi, pi], ``reach`` (N, 8), ``singular`` (N, 8)."""
        ...

    def ik_branch_cols(self, C: np.ndarray, branch: int, q1_hold: np.ndarray | None = None,
                       q_free: float | np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One branch: ``q`` (nq, N), ``reach``, ``singular`` and ``gap_rad`` (N,).

        ``gap_rad`` is a lower bound on the joint-space distance (angles
        modulo 2*pi) from this branch to every other branch of the row, at most pi.
        """
        ...

    def wrist_sin(self, q: np.ndarray) -> np.ndarray:
        """Distance from the wrist singularity of joints (nq, N) as ``|sin|`` of the wrist bend (N,), 0 there."""
        ...

    def wrist_degenerate(self, q: np.ndarray) -> np.ndarray:
        """Rows of joints (nq, N) exactly at the wrist singularity, where one wrist angle is free.

        Such rows are always among those the IK flags singular; the solver asks only about those."""
        ...

    def resolve_wrist(self, C: np.ndarray, q: np.ndarray, held: np.ndarray) -> np.ndarray:
        """Joints (nq, M) of wrist-degenerate rows with the free angle taken from ``held`` (nq, M), still exact."""
        ...

    def model_cols(self, C: np.ndarray) -> np.ndarray:
        """End-frame columns (9, N) in the family's own model base (its closed form's frame)."""
        ...

    def native_constants(self) -> list[float]:
        """The family's constants in the order the C tracking reads them (``fabric/native/armik.c``)."""
        ...


def stack_branches(res: dict[int, tuple[np.ndarray, ...]], nq: int, n: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A family's branches as ``ik_branches_cols`` returns them: from ``{branch: (q (nq, N), reach (N,),
    singular (N,), ...)}`` for all 8 branches to ``q (N, 8, nq), reach (N, 8), singular (N, 8)``."""
    qt = np.empty((8, nq, n))
    reach = np.empty((n, 8), dtype=bool)
    sing = np.empty((n, 8), dtype=bool)
    for b, (q, ok, sg, _) in res.items():
        qt[b], reach[:, b], sing[:, b] = q, ok, sg
    return qt.transpose(2, 0, 1), reach, sing


def cols_in_frame(frame_T: np.ndarray | None, C: np.ndarray) -> np.ndarray:
    """The nine pose columns ``C`` (position, z and y axes; ``kinematics.pose_cols``) expressed in the frame
    ``frame_T`` (4x4, in the columns' frame; None: the same frame, ``C`` itself): a family's own base when the
    URDF places axis 1 elsewhere."""
    if frame_T is None:
        return C
    R, t = frame_T[:3, :3], frame_T[:3, 3]
    out = np.empty_like(C)
    out[0:3] = R.T @ (C[0:3] - t[:, None])
    out[3:6] = R.T @ C[3:6]
    out[6:9] = R.T @ C[6:9]
    return out
