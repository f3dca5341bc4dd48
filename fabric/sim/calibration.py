"""Work-object calibration: probe the plate with simulated touch sensing and fit its true frame.

The plate is a box ``[lo, hi]`` in its own frame (top face ``z = hi_z``). The
robot believes the plate is at ``nominal_T`` (plate frame in the base frame);
it really is at ``true_T``. Probing, as a touch probe on the nozzle does it:

* **top**: a grid of points; from above each nominal point the probe moves
  down the nozzle axis (the nominal plate -z) until it touches the true top
  plane: an analytic ray-plane intersection;
* **sides**: once the top is known, the probe goes a few mm below the fitted
  top surface, outside the ``x = lo_x`` face and then the ``y = lo_y`` face, and
  moves sideways (nominal +x, then +y) until it touches that face.

Each touch gets Gaussian noise (``noise_mm`` per axis: the probe's trigger and
the robot's repeatability). The fit is a least-squares problem over a small
correction ``E = (t, rpy)`` of the nominal frame, ``T = nominal_T @ E``: top
touches must satisfy ``(T^-1 p)_z = hi_z``, x-face touches ``(T^-1 p)_x = lo_x``,
y-face touches ``(T^-1 p)_y = lo_y``. The top plane fixes z, roll and pitch;
the faces fix x, y and yaw (two faces, several touches each, far apart, so the
yaw is well conditioned). The residual RMS tells how well the touches agree.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from fabric.robot.frames import T_to_xyzrpy, inv_T, xyzrpy_to_T
from fabric.wire.errors import ConfigError

__all__ = ["CalibrationResult", "ProbePlan", "probe_plan", "simulate_touches", "fit_plate", "top_plane_frame",
           "calibrate_plate", "TOP", "SIDE_X", "SIDE_Y"]

TOP, SIDE_X, SIDE_Y = 0, 1, 2


@dataclass
class ProbePlan:
    """Probe starts (plate frame, nominal), unit directions (plate frame) and the face each aims at."""

    start_mm: np.ndarray
    dir: np.ndarray
    kind: np.ndarray


@dataclass
class CalibrationResult:
    """The fitted plate frame, the correction from nominal and the fit quality."""

    work_object_T: np.ndarray
    correction_xyz_mm: np.ndarray
    correction_rpy_deg: np.ndarray
    residual_rms_mm: float
    n_points: int
    points_base_mm: np.ndarray
    kind: np.ndarray


def probe_plan(lo_mm: np.ndarray, hi_mm: np.ndarray, *, grid: int = 3, margin_mm: float = 20.0,
               side_points: int = 4, clearance_mm: float = 10.0, depth_mm: float = 3.0,
               kinds: tuple[int, ...] = (TOP, SIDE_X, SIDE_Y)) -> ProbePlan:
    """Probe starts on the plate: a ``grid x grid`` on the top, ``side_points`` on each of two faces."""
    lo, hi = np.asarray(lo_mm, float), np.asarray(hi_mm, float)
    starts, dirs, kind = [], [], []
    if TOP in kinds:
        gx = np.linspace(lo[0] + margin_mm, hi[0] - margin_mm, grid)
        gy = np.linspace(lo[1] + margin_mm, hi[1] - margin_mm, grid)
        X, Y = np.meshgrid(gx, gy, indexing="ij")
        n = X.size
        starts.append(np.stack([X.ravel(), Y.ravel(), np.full(n, hi[2] + clearance_mm)], 1))
        dirs.append(np.tile([0.0, 0.0, -1.0], (n, 1)))
        kind.append(np.full(n, TOP))
    z = hi[2] - depth_mm
    if SIDE_X in kinds:
        ys = np.linspace(lo[1] + margin_mm, hi[1] - margin_mm, side_points)
        starts.append(np.stack([np.full(side_points, lo[0] - clearance_mm), ys, np.full(side_points, z)], 1))
        dirs.append(np.tile([1.0, 0.0, 0.0], (side_points, 1)))
        kind.append(np.full(side_points, SIDE_X))
    if SIDE_Y in kinds:
        xs = np.linspace(lo[0] + margin_mm, hi[0] - margin_mm, side_points)
        starts.append(np.stack([xs, np.full(side_points, lo[1] - clearance_mm), np.full(side_points, z)], 1))
        dirs.append(np.tile([0.0, 1.0, 0.0], (side_points, 1)))
        kind.append(np.full(side_points, SIDE_Y))
    return ProbePlan(np.concatenate(starts), np.concatenate(dirs), np.concatenate(kind))


def _face(kind: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Plate-frame axis index and offset of the face each probe aims at."""
    axis = np.select([kind == TOP, kind == SIDE_X], [2, 0], 1)
    off = np.select([kind == TOP, kind == SIDE_X], [hi[2], lo[0]], lo[1])
    return axis, off


def simulate_touches(plan: ProbePlan, probe_T: np.ndarray, true_T: np.ndarray, lo_mm: np.ndarray,
                     hi_mm: np.ndarray, noise_mm: float, rng: np.random.Generator) -> np.ndarray:
    """Touch points (base frame, mm): rays from ``probe_T @ start`` along ``probe_T``'s directions
    against the true plate's faces, plus noise. Raises ConfigError when a probe misses the plate."""
    lo, hi = np.asarray(lo_mm, float), np.asarray(hi_mm, float)
    p0 = plan.start_mm @ probe_T[:3, :3].T + probe_T[:3, 3]
    d = plan.dir @ probe_T[:3, :3].T
    inv = inv_T(true_T)
    q0 = p0 @ inv[:3, :3].T + inv[:3, 3]          # in the true plate frame
    qd = d @ inv[:3, :3].T
    axis, off = _face(plan.kind, lo, hi)
    k = np.arange(len(axis))
    denom = qd[k, axis]
    if np.any(np.abs(denom) < 1e-9):
        raise ConfigError("a probe runs parallel to the face it should touch", field="probe")
    t = (off - q0[k, axis]) / denom
    hit = q0 + t[:, None] * qd
    inside = np.all((hit >= lo - 1e-6) & (hit <= hi + 1e-6), axis=1) & (t > 0)
    if not inside.all():
        bad = int(np.flatnonzero(~inside)[0])
        raise ConfigError(f"probe {bad} missed the plate (plate error too large for the probe plan)",
                          field="probe", probe=bad, kind=int(plan.kind[bad]))
    return p0 + t[:, None] * d + rng.normal(0.0, noise_mm, size=p0.shape)


def _residuals(x: np.ndarray, nominal_T: np.ndarray, pts: np.ndarray, axis: np.ndarray,
               off: np.ndarray) -> np.ndarray:
    T = nominal_T @ xyzrpy_to_T(x[:3], np.degrees(x[3:]))
    inv = inv_T(T)
    local = pts @ inv[:3, :3].T + inv[:3, 3]
    return local[np.arange(len(axis)), axis] - off


def fit_plate(points_base_mm: np.ndarray, kind: np.ndarray, nominal_T: np.ndarray, lo_mm: np.ndarray,
              hi_mm: np.ndarray) -> CalibrationResult:
    """Least-squares plate frame from touches (see module docstring)."""
    lo, hi = np.asarray(lo_mm, float), np.asarray(hi_mm, float)
    axis, off = _face(kind, lo, hi)
    need = {TOP: 3, SIDE_X: 2, SIDE_Y: 1}
    for k, n in need.items():
        if np.count_nonzero(kind == k) < n:
            raise ConfigError(f"calibration needs at least {n} touches of face {k}", field="probe")
    sol = least_squares(_residuals, np.zeros(6), args=(nominal_T, points_base_mm, axis, off),
                        method="lm", xtol=1e-14, ftol=1e-14)
    E = xyzrpy_to_T(sol.x[:3], np.degrees(sol.x[3:]))
    xyz, rpy = T_to_xyzrpy(E)
    rms = float(np.sqrt(np.mean(sol.fun ** 2)))
    return CalibrationResult(nominal_T @ E, xyz, rpy, rms, len(kind), points_base_mm, kind)


def top_plane_frame(points_base_mm: np.ndarray, nominal_T: np.ndarray, hi_z_mm: float) -> np.ndarray:
    """The nominal frame corrected in z, roll and pitch by a plane fit ``z = c0 + c1 x + c2 y`` of
    top touches (in the nominal plate frame): where the side probes should aim below the top."""
    inv = inv_T(nominal_T)
    local = points_base_mm @ inv[:3, :3].T + inv[:3, 3]
    A = np.stack([np.ones(len(local)), local[:, 0], local[:, 1]], 1)
    c, *_ = np.linalg.lstsq(A, local[:, 2], rcond=None)
    n = np.array([-c[1], -c[2], 1.0])
    n /= np.linalg.norm(n)
    x = np.array([1.0, 0.0, 0.0]) - n[0] * n
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(n, x), n], 1)
    E = np.eye(4)
    E[:3, :3] = R
    E[2, 3] = c[0] - hi_z_mm
    return nominal_T @ E


def calibrate_plate(nominal_T: np.ndarray, true_T: np.ndarray, lo_mm: np.ndarray, hi_mm: np.ndarray,
                    noise_mm: float, rng: np.random.Generator, *, grid: int = 4,
                    side_points: int = 6) -> tuple[CalibrationResult, ProbePlan, np.ndarray]:
    """Both probing stages and the fit. Returns the result, the full probe plan and the frame each
    probe was planned in (stacked (N, 4, 4)), for reachability checks by the caller."""
    nominal_T = np.asarray(nominal_T, float)
    top = probe_plan(lo_mm, hi_mm, grid=grid, kinds=(TOP,))
    p_top = simulate_touches(top, nominal_T, true_T, lo_mm, hi_mm, noise_mm, rng)
    side_T = top_plane_frame(p_top, nominal_T, float(np.asarray(hi_mm)[2]))
    sides = probe_plan(lo_mm, hi_mm, side_points=side_points, kinds=(SIDE_X, SIDE_Y))
    p_side = simulate_touches(sides, side_T, true_T, lo_mm, hi_mm, noise_mm, rng)
    pts = np.concatenate([p_top, p_side])
    kind = np.concatenate([top.kind, sides.kind])
    plan = ProbePlan(np.concatenate([top.start_mm, sides.start_mm]), np.concatenate([top.dir, sides.dir]), kind)
    frames = np.concatenate([np.broadcast_to(nominal_T, (len(top.kind), 4, 4)),
                             np.broadcast_to(side_T, (len(sides.kind), 4, 4))])
    return fit_plate(pts, kind, nominal_T, lo_mm, hi_mm), plan, frames
