"""Baseline for the planning benchmark: per-point Pinocchio damped-least-squares IK.

This is the "per-point numerical IK" the product brief compares against, written
the standard way and not handicapped: for each target, start from the previous
solution (the first from ``q_seed``), iterate

    e  = log6(T_tcp(q)^-1 T_target)          (TCP frame, metres / radians)
    J  = Jlog6 @ J_tcp(q)                    (TCP-frame Jacobian, Pinocchio)
    dq = J^T (J J^T + lambda^2 I)^-1 e       (damped least squares, lambda^2 = 1e-6)
    q  = integrate(q, dq)

until ``|e_lin| < 1e-6 m`` and ``|e_ang| < 1e-6 rad`` or 100 iterations.

:func:`dls_ik_warm` is the same iteration warm-started *along the path*, as a
user walking a toolpath would write it: each target starts from the joints
extrapolated from the two solutions before it (``q_{i-1} + (q_{i-1} - q_{i-2})``),
so on a path of short, even steps most targets converge in one iteration
(measured: 1.05 iterations per target on the planning benchmark's raster, against
about two from the previous solution; the issue measured 27.6 us per point against
38.8). It is the faster baseline, the one the planning benchmark's ratios use.

Run as a script to time it against the closed form::

    .venv/bin/python tools/bench/ik_baseline.py [n_points]
"""
from __future__ import annotations

import sys
import time

import numpy as np
import pinocchio as pin

TOL_M = 1e-6
TOL_RAD = 1e-6
MAX_ITER = 100
DAMPING = 1e-6


def dls_ik(robot, T: np.ndarray, q_seed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Joints (N, nq) and converged flags (N,) for TCP poses T (N, 4, 4) in mm (robot base frame)."""
    return _dls(robot, T, q_seed, None)


def dls_ik_warm(robot, T: np.ndarray, q_seed: np.ndarray, q_before: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`dls_ik` warm-started along the path: each target from the joints extrapolated from the two
    solutions before it (``q_seed`` is the solution before the first target, ``q_before`` the one before
    that; without it the first target starts from ``q_seed``)."""
    return _dls(robot, T, q_seed, q_seed if q_before is None else q_before)


def _dls(robot, T: np.ndarray, q_seed: np.ndarray, q_before: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    model, data, fid = robot.pin_model, robot.pin_data, robot.tcp_frame_id
    T = np.asarray(T, dtype=float).reshape(-1, 4, 4)
    q_out = np.empty((len(T), model.nq))
    ok = np.zeros(len(T), dtype=bool)
    q = np.asarray(q_seed, dtype=float).copy()
    prev = None if q_before is None else np.asarray(q_before, dtype=float).copy()
    eye = np.eye(6)
    for i in range(len(T)):
        target = pin.SE3(T[i, :3, :3].copy(), T[i, :3, 3] / 1000.0)
        if prev is not None:                     # warm start along the path: extrapolate the last step
            q, prev = q + (q - prev), q
        for _ in range(MAX_ITER):
            pin.forwardKinematics(model, data, q)
            err_T = pin.updateFramePlacement(model, data, fid).actInv(target)
            err = pin.log6(err_T).vector
            if np.linalg.norm(err[:3]) < TOL_M and np.linalg.norm(err[3:]) < TOL_RAD:
                ok[i] = True
                break
            J = pin.Jlog6(err_T) @ pin.computeFrameJacobian(model, data, q, fid, pin.ReferenceFrame.LOCAL)
            q = pin.integrate(model, q, J.T @ np.linalg.solve(J @ J.T + DAMPING * eye, err))
        q_out[i] = q
    return q_out, ok


def _raster_targets(robot, n: int) -> np.ndarray:
    """n TCP poses along a serpentine raster over the IRB 140 plate, nozzle down."""
    from fabric.robot.frames import make_T
    side = max(2, int(np.sqrt(n)))
    t = np.arange(n)
    row, col = t // side, t % side
    col = np.where(row % 2 == 0, col, side - 1 - col)
    x = 475.0 + 250.0 * col / (side - 1)
    y = -125.0 + 250.0 * (row % side) / (side - 1)
    z = np.full(n, 200.0 + 0.2 * (row // side))
    R = np.array([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])
    return make_T(np.broadcast_to(R, (n, 3, 3)), np.stack([x, y, z], axis=1))


def main(argv: list[str]) -> None:
    from fabric.robot.model import IRB140_URDF, RobotModel
    n_dls = int(argv[1]) if len(argv) > 1 else 2000
    n_cf = int(argv[2]) if len(argv) > 2 else 1_000_000
    robot = RobotModel.from_urdf(IRB140_URDF)
    seed = np.radians([0.0, 10.0, -10.0, 0.0, 90.0, 0.0])
    T = _raster_targets(robot, n_dls)
    t0 = time.perf_counter()
    _q, ok = dls_ik(robot, T, seed)
    dt_dls = time.perf_counter() - t0
    Tc = _raster_targets(robot, n_cf)
    t0 = time.perf_counter()
    _qc, st = robot.ik(Tc, seed)
    dt_cf = time.perf_counter() - t0
    t0 = time.perf_counter()
    _q, ok_w = dls_ik_warm(robot, T, seed)
    dt_warm = time.perf_counter() - t0
    print(f"DLS baseline : {n_dls} targets in {dt_dls:.3f} s = {n_dls / dt_dls:,.0f} targets/s "
          f"({ok.mean():.1%} converged)")
    print(f"DLS, warm    : {n_dls} targets in {dt_warm:.3f} s = {n_dls / dt_warm:,.0f} targets/s "
          f"({ok_w.mean():.1%} converged)")
    print(f"closed form  : {n_cf} targets in {dt_cf:.3f} s = {n_cf / dt_cf:,.0f} targets/s "
          f"({(st == 0).mean():.1%} ok)")
    print(f"speed-up     : {(n_cf / dt_cf) / (n_dls / dt_dls):.0f}x")


if __name__ == "__main__":
    main(sys.argv)
