"""Numeric IK for any serial arm: Pinocchio damped least squares on the SE3 log error.

:class:`NumericIK` needs only the Pinocchio model, the joint limits and the TCP
frame id, and has the interface of the closed-form solver
(:class:`fabric.robot.closed_form.ClosedFormIK`): ``solve(T_tcp_mm, q_seed) ->
(q, status)``. :class:`~fabric.robot.model.RobotModel` uses it when no closed
form applies and the arm has joints other than revolute ones.

Each row starts from the previous row's solution (row 0 from the seed), so a
smooth path stays on one configuration. The error is ``log6(T_current^-1 T_target)``
in the TCP frame (metres, radians) and the step is the damped pseudo-inverse
``dq = J^T (J J^T + lambda^2 I)^-1 e`` with the TCP-frame Jacobian; joints are
clipped to their limits after each step so the solver looks for in-limit
solutions. A row that does not converge from the warm start is retried from the
seed and from the middle of the joint ranges, then once without clipping: a
solution found only beyond the limits is ``IK_JOINT_LIMIT``, no solution at all
``IK_OUT_OF_REACH`` (the row then holds the previous joints);
one whose Jacobian's smallest singular value (linear rows in metres) is below
``SINGULAR_SIGMA`` is ``IK_SINGULAR``.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from fabric.robot.kinematics import IK_JOINT_LIMIT, IK_OK, IK_OUT_OF_REACH, IK_SINGULAR

__all__ = ["NumericIK", "SINGULAR_SIGMA"]

SINGULAR_SIGMA = 5e-3
TOL_M = 1e-7
TOL_RAD = 1e-7
MAX_ITER = 100
DAMPING = 1e-6
LIMIT_TOL_RAD = 1e-9


class NumericIK:
    """Damped-least-squares IK of a Pinocchio model within joint limits, on TCP poses (mm).

    Not thread-safe: it owns one Pinocchio ``Data``; give each thread its own solver.
    """

    def __init__(self, pin_model: pin.Model, lower_rad: np.ndarray, upper_rad: np.ndarray,
                 tcp_frame_id: int) -> None:
        self.model = pin_model
        self.data = pin_model.createData()
        self.nq = int(pin_model.nq)
        self.lower_rad = np.asarray(lower_rad, dtype=float).copy()
        self.upper_rad = np.asarray(upper_rad, dtype=float).copy()
        self.tcp_frame_id = int(tcp_frame_id)

    def solve(self, T_tcp_mm: np.ndarray, q_seed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Joints (N, nq) and status (N,) uint8 for TCP poses (N, 4, 4) mm, warm-started row to row."""
        T = np.asarray(T_tcp_mm, dtype=float).reshape(-1, 4, 4)
        seed = np.asarray(q_seed, dtype=float).reshape(self.nq)
        n = len(T)
        q_out = np.empty((n, self.nq))
        status = np.empty(n, dtype=np.uint8)
        mid = 0.5 * (np.maximum(self.lower_rad, -np.pi) + np.minimum(self.upper_rad, np.pi))
        prev = seed.copy()
        for i in range(n):
            target = pin.SE3(T[i, :3, :3].copy(), T[i, :3, 3] / 1000.0)
            for start in (prev, seed, mid):
                q, ok, J = self.solve_one(target, start)
                if ok:
                    break
            else:  # no in-limit solution found: is there one beyond the limits?
                q, ok, J = self.solve_one(target, prev, clip=False)
            if not ok:
                q_out[i], status[i] = prev, IK_OUT_OF_REACH
                continue
            q_out[i] = q
            if not self.within_limits(q):
                status[i] = IK_JOINT_LIMIT             # keep warm-starting from the last in-limit row
                continue
            prev = q
            if np.linalg.svd(J, compute_uv=False)[-1] < SINGULAR_SIGMA:
                status[i] = IK_SINGULAR
            else:
                status[i] = IK_OK
        return q_out, status

    def solve_one(self, target: pin.SE3, q0: np.ndarray, max_iter: int = MAX_ITER,
                  clip: bool = True) -> tuple[np.ndarray, bool, np.ndarray]:
        """One DLS solve from ``q0`` towards ``target`` (metres): ``(q, converged, J)``.

        ``J`` is the last TCP-frame Jacobian (its smallest singular value flags a singularity)."""
        model, data, frame_id = self.model, self.data, self.tcp_frame_id
        q = np.array(q0, dtype=float)
        J = np.zeros((6, model.nv))
        for _ in range(max_iter):
            pin.forwardKinematics(model, data, q)
            cur = pin.updateFramePlacement(model, data, frame_id)
            err = pin.log6(cur.actInv(target)).vector
            J = pin.computeFrameJacobian(model, data, q, frame_id, pin.ReferenceFrame.LOCAL)
            if np.linalg.norm(err[:3]) < TOL_M and np.linalg.norm(err[3:]) < TOL_RAD:
                return q, True, J
            # J_log6 maps joint rates to the rate of the log error; near convergence it is ~identity
            Jl = pin.Jlog6(cur.actInv(target)) @ J
            dq = Jl.T @ np.linalg.solve(Jl @ Jl.T + DAMPING * np.eye(6), err)
            q = pin.integrate(model, q, dq)
            if clip:
                q = np.clip(q, self.lower_rad, self.upper_rad)
        return q, False, J

    def within_limits(self, q: np.ndarray) -> bool:
        """Joints ``q`` (nq,) inside the position limits."""
        return bool(np.all((q >= self.lower_rad - LIMIT_TOL_RAD) & (q <= self.upper_rad + LIMIT_TOL_RAD)))
