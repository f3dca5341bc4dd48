"""The tilts a cell's arm can hold the nozzle at over the part: per place and direction of lean, the largest.

The curved slicer limits the nozzle axis to ``max_tilt_deg`` from +z all round
(:mod:`.axis`). An arm holds some leans better than others: on
``irb140-multiaxis`` a vertical nozzle over the plate bends the wrist (A5) by
about 65 degrees, a nozzle leaning 45 degrees towards the robot by about 20,
and one leaning 45 degrees away from it by 123, past A5's 115: a hook curling
away from the robot planned 2676 targets at that limit. So the slicer asks the
arm before it chooses an axis, not the planner after.

For each node of a grid over the part (``GRID_MM`` apart, plate frame) and
each direction of lean (``AZIMUTH_STEP_DEG`` apart), the largest tilt
``t`` (of ``TILT_STEP_DEG`` steps, up to the options' limit) such that every
tilt from 0 to ``t`` is held by the arm: some rotation about the nozzle (the
planner's free rotation, ``ROTATIONS`` candidates) reaches the pose in the
configuration the planner keeps from the cell's home (its IK branch), with
every joint of less than a turn ``JOINT_MARGIN_DEG`` inside its limits (the
multi-turn ones are wound by the planner) and the wrist bent at least
``WRIST_MARGIN_DEG`` off its singularity. A query takes the least of the
grid cell's eight corners and of the two sampled directions on either side:
a tilt it allows is held at every corner of the cell it lies in.

Only arms with a closed-form IK are asked (every built-in cell's); for others
:meth:`CellTilts.of_cell` answers None and the options' limit alone holds.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from fabric.robot.frames import frame_from_z_axis
from fabric.robot.kinematics import pose_cols

__all__ = ["CellTilts", "GRID_MM", "AZIMUTH_STEP_DEG", "TILT_STEP_DEG", "JOINT_MARGIN_DEG", "WRIST_MARGIN_DEG"]

GRID_MM = 10.0                 # grid nodes over the part, at most this far apart
AZIMUTH_STEP_DEG = 10.0        # directions of lean sampled
TILT_STEP_DEG = 2.5            # tilts sampled along each
ROTATIONS = 12                 # rotations about the nozzle tried (30 degrees apart)
JOINT_MARGIN_DEG = 3.0         # a joint held this far inside its limits
WRIST_MARGIN_DEG = 8.0         # the wrist bent at least this far off its singularity
PAD_MM = 1.0                   # the grid reaches this far past the part's bounds


@dataclass(frozen=True)
class CellTilts:
    """The largest tilt (deg) per grid node and direction of lean (module docstring)."""

    lo_mm: np.ndarray            # (3,) the grid's first node, plate frame
    step_mm: np.ndarray          # (3,) between nodes
    max_tilt_deg: np.ndarray     # (nx, ny, nz, n_azimuths) every tilt up to it is held
    cell_name: str = ""

    @classmethod
    def of_cell(cls, cell: Any, bounds_mm: np.ndarray, max_tilt_deg: float) -> CellTilts | None:
        """The tilts ``cell`` (a :class:`fabric.robot.cell.Cell`) holds over ``bounds_mm`` ((2, 3), plate frame),
        up to ``max_tilt_deg``; None for an arm without a closed-form IK."""
        cf = cell.robot.closed_form
        if cf is None:
            return None
        lo = np.asarray(bounds_mm[0], dtype=float) - PAD_MM
        hi = np.asarray(bounds_mm[1], dtype=float) + PAD_MM
        counts = np.maximum(np.ceil((hi - lo) / GRID_MM).astype(int) + 1, 2)
        step = (hi - lo) / (counts - 1)
        axes = [lo[k] + step[k] * np.arange(counts[k]) for k in range(3)]
        nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        held = _held_tilts(cell, nodes, max_tilt_deg)
        return cls(lo, step, held.reshape(*counts, -1), str(getattr(cell, "name", "")))

    def limit_deg(self, points_mm: np.ndarray, axes: np.ndarray) -> np.ndarray:
        """(n,) the largest tilt held at each point along the direction its axis leans (module docstring)."""
        p = np.asarray(points_mm, dtype=float)
        a = np.asarray(axes, dtype=float)
        if len(p) == 0:
            return np.zeros(0)
        shape = np.array(self.max_tilt_deg.shape[:3])
        f = (p - self.lo_mm) / self.step_mm
        i0 = np.clip(np.floor(f).astype(int), 0, shape - 2)
        n_az = self.max_tilt_deg.shape[3]
        az = np.mod(np.degrees(np.arctan2(a[:, 1], a[:, 0])), 360.0) / (360.0 / n_az)
        a0 = np.floor(az).astype(int) % n_az
        a1 = (a0 + 1) % n_az
        out = np.full(len(p), np.inf)
        for corner in range(8):
            d = np.array([(corner >> k) & 1 for k in range(3)])
            ix, iy, iz = (i0 + d).T
            out = np.minimum(out, np.minimum(self.max_tilt_deg[ix, iy, iz, a0], self.max_tilt_deg[ix, iy, iz, a1]))
        return out


def _held_tilts(cell: Any, nodes_mm: np.ndarray, max_tilt_deg: float) -> np.ndarray:
    """(n_nodes, n_azimuths) the largest tilt held at each node along each sampled direction of lean."""
    n_az = int(round(360.0 / AZIMUTH_STEP_DEG))
    tilts = np.arange(0.0, max_tilt_deg + 1e-9, TILT_STEP_DEG)
    if tilts[-1] < max_tilt_deg - 1e-9:
        tilts = np.append(tilts, max_tilt_deg)
    az = np.radians(np.arange(n_az) * AZIMUTH_STEP_DEG)
    t = np.radians(tilts)
    # directions (n_az, n_tilt, 3), plate frame
    dirs = np.stack([np.sin(t)[None, :] * np.cos(az)[:, None], np.sin(t)[None, :] * np.sin(az)[:, None],
                     np.broadcast_to(np.cos(t)[None, :], (n_az, len(t)))], axis=-1)
    ok = np.zeros((len(nodes_mm), n_az, len(t)), dtype=bool)
    check = _PoseCheck(cell)
    for i, p in enumerate(nodes_mm):
        ok[i] = check.held(p, dirs.reshape(-1, 3)).reshape(n_az, len(t))
    # the largest tilt every smaller one of which is held too (0 where even the vertical is not: unreachable)
    first_bad = np.where(ok.all(axis=2), len(t), np.argmin(ok, axis=2))
    return np.where(first_bad > 0, tilts[np.maximum(first_bad - 1, 0)], 0.0)


class _PoseCheck:
    """Whether the arm holds the nozzle at a point along given axes (module docstring)."""

    def __init__(self, cell: Any) -> None:
        robot = cell.robot
        self.cf = robot.closed_form
        self.wobj = np.asarray(cell.wobj_T(), dtype=float)
        self.rotations = np.radians(np.arange(ROTATIONS) * 360.0 / ROTATIONS)
        single = ~self.cf.multi
        self.joints = np.flatnonzero(single)
        margin = math.radians(JOINT_MARGIN_DEG)
        self.lower = self.cf.lower_rad[self.joints] + margin
        self.upper = self.cf.upper_rad[self.joints] - margin
        self.wrist_sin = math.sin(math.radians(WRIST_MARGIN_DEG))
        self.branch = _home_branch(self.cf, np.asarray(cell.home_q_rad, dtype=float))

    def held(self, point_mm: np.ndarray, axes: np.ndarray) -> np.ndarray:
        """(m,) each unit axis (plate frame) held at ``point_mm`` by some rotation about it."""
        R = self.wobj[:3, :3]
        p = self.wobj[:3, :3] @ point_mm + self.wobj[:3, 3]
        z = -(axes @ R.T)                                  # the TCP's z points out of the nozzle: down the axis
        x_ref = np.array([-p[0], -p[1], 0.0])             # theta 0 as the planner's (towards the A1 axis)
        frames = frame_from_z_axis(z, x_ref)
        m = len(axes)
        out = np.zeros(m, dtype=bool)
        for theta in self.rotations:
            c, s = math.cos(theta), math.sin(theta)
            T = np.zeros((m, 4, 4))
            T[:, :3, 0] = c * frames[:, :, 0] + s * frames[:, :, 1]
            T[:, :3, 1] = c * frames[:, :, 1] - s * frames[:, :, 0]
            T[:, :3, 2] = frames[:, :, 2]
            T[:, :3, 3] = p
            T[:, 3, 3] = 1.0
            cols = pose_cols(T, self.cf.tool_inv_T)
            q, reach, _sing, _gap = self.cf.arm.ik_branch_cols(cols, self.branch, None, self.cf.free_rad
                                                               if self.cf.free_joint is not None else None)
            qn = np.ascontiguousarray(q.T)
            _q, _inlim = self.cf.canon(qn)
            inside = np.all((qn[:, self.joints] >= self.lower) & (qn[:, self.joints] <= self.upper), axis=1)
            bent = self.cf.wrist_sin(qn) >= self.wrist_sin
            out |= reach & inside & bent
            if out.all():
                break
        return out


def _home_branch(cf: Any, home_q: np.ndarray) -> int:
    """The IK branch the planner keeps: the one of the cell's home joints."""
    T = cf.fk_flange(home_q)
    qb, _ok, reach, _sing = cf.branches(T[None], None, cf.free_rad if cf.free_joint is not None else None)
    d = np.abs(np.angle(np.exp(1j * (qb[0] - home_q[None, :])))).sum(axis=1)
    d[~reach[0]] = np.inf
    return int(np.argmin(d))
