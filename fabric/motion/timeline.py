"""The timed schedule of a program (a ``Timeline``) and its evaluation at any simulated time.

A timeline covers program rows ``start_row .. start_row + n - 1``. Row ``i``
runs from ``t_start_s[i]`` to ``t_end_s[i]`` (seconds from the timeline's own
start); the total is the sum of the row durations, whatever step a simulation
later uses to walk through it.

Linear moves (MOVEL) follow a trapezoid-like speed profile over the distance
``len_mm[i]`` the row covers in this timeline: phase 1 changes speed from
``v0`` to ``vc`` at the acceleration limit (up *or* down: after a speed
override the entry speed may exceed the new cruise speed), phase 2 cruises at
``vc``, phase 3 changes from ``vc`` to ``v1``. The TCP moves in a straight line
in the plate frame from the previous row's target to this row's target; the
covered part starts ``s0_mm`` along it (non-zero only for a first row resumed
mid-way). Joints along a linear move are interpolated linearly between the two
rows' joint targets (the planner splits every move where that would take the
TCP further than ``linear_tol_mm``, 0.1 mm by default, from the straight line:
``fabric.planning.refine``; the Cartesian position is exact), and the orientation by normalised
quaternion interpolation. Joint moves (MOVEJ) are Ruckig jerk-limited
trajectories evaluated with ``Trajectory.at_time``; their TCP comes from
forward kinematics. Other rows hold the row's pose.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fabric.motion.program import MOVEJ, MOVEL, Program
from fabric.robot.frames import inv_T, nlerp_quat, quat_from_R

__all__ = ["Sample", "SampleBatch", "Timeline"]


@dataclass
class Sample:
    """The commanded state at one time: row, joints, TCP (plate frame), speed and extrusion."""

    row: int
    q_rad: np.ndarray
    xyz_mm: np.ndarray
    quat_wxyz: np.ndarray
    tcp_speed_mm_s: float
    extruding: bool
    flow_mm3_s: float
    progress: float
    base_xyz_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    s_mm: float = 0.0


@dataclass
class SampleBatch:
    """``Timeline.sample_many``: the fields of :class:`Sample` stacked over M times."""

    row: np.ndarray
    q_rad: np.ndarray
    xyz_mm: np.ndarray
    quat_wxyz: np.ndarray
    tcp_speed_mm_s: np.ndarray
    extruding: np.ndarray
    flow_mm3_s: np.ndarray
    progress: np.ndarray
    base_xyz_mm: np.ndarray
    s_mm: np.ndarray

    def __len__(self) -> int:
        return len(self.row)

    def __getitem__(self, k: int) -> Sample:
        return Sample(int(self.row[k]), self.q_rad[k], self.xyz_mm[k], self.quat_wxyz[k],
                      float(self.tcp_speed_mm_s[k]), bool(self.extruding[k]), float(self.flow_mm3_s[k]),
                      float(self.progress[k]), self.base_xyz_mm[k], float(self.s_mm[k]))


@dataclass
class Timeline:
    """The exact schedule of rows ``start_row ..`` of ``program`` (see module docstring)."""

    program: Program
    robot: Any
    start_row: int
    t_start_s: np.ndarray
    t_end_s: np.ndarray
    v0_mm_s: np.ndarray
    vc_mm_s: np.ndarray
    v1_mm_s: np.ndarray
    t1_s: np.ndarray
    tc_s: np.ndarray
    t3_s: np.ndarray
    len_mm: np.ndarray
    accel_mm_s2: float
    first_from_q_rad: np.ndarray
    first_from_xyz_mm: np.ndarray
    first_from_quat_wxyz: np.ndarray
    s0_mm: float = 0.0
    speed_r: float = 1.0
    flow_r: float = 1.0
    joint_traj: dict[int, Any] = field(default_factory=dict)
    slowed_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    slowed_joint: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def n(self) -> int:
        """Number of rows timed."""
        return len(self.t_end_s)

    @property
    def total_s(self) -> float:
        """Duration of the whole timeline (the sum of the row durations)."""
        return float(self.t_end_s[-1]) if self.n else 0.0

    @property
    def rows(self) -> np.ndarray:
        """Absolute program row of each timeline row."""
        return self.start_row + np.arange(self.n)

    @property
    def duration_s(self) -> np.ndarray:
        """Duration of each row."""
        return self.t_end_s - self.t_start_s

    # Where each row starts from ------------------------------------------------

    def from_pose(self, i: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Full-row start (q, xyz, quat) of local rows ``i``: the previous row's targets."""
        p = self.program
        prev = np.maximum(self.start_row + i - 1, 0)
        q, xyz, quat = p.q_rad[prev].copy(), p.xyz_mm[prev].copy(), p.quat_wxyz[prev].copy()
        first = i == 0
        q[first], xyz[first], quat[first] = self.first_from_q_rad, self.first_from_xyz_mm, self.first_from_quat_wxyz
        return q, xyz, quat

    def row_length_mm(self, i: np.ndarray) -> np.ndarray:
        """Full straight-line length of local rows ``i`` (0 for non-MOVEL rows)."""
        _, a, _ = self.from_pose(i)
        L = np.linalg.norm(self.program.xyz_mm[self.start_row + i] - a, axis=-1)
        return np.where(self.program.op[self.start_row + i] == MOVEL, L, 0.0)

    # Speed profile ----------------------------------------------------------------

    def profile(self, i: np.ndarray, tau_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance (mm, from where the row's covered part begins) and speed at local time ``tau_s``."""
        a = self.accel_mm_s2
        v0, vc, v1 = self.v0_mm_s[i], self.vc_mm_s[i], self.v1_mm_s[i]
        t1, tc, t3 = self.t1_s[i], self.tc_s[i], self.t3_s[i]
        a1 = np.sign(vc - v0) * a
        a3 = np.sign(v1 - vc) * a
        tau = np.clip(tau_s, 0.0, t1 + tc + t3)
        u1 = np.minimum(tau, t1)
        u2 = np.clip(tau - t1, 0.0, tc)
        u3 = np.clip(tau - t1 - tc, 0.0, t3)
        s = v0 * u1 + 0.5 * a1 * u1 ** 2 + vc * u2 + vc * u3 + 0.5 * a3 * u3 ** 2
        v = np.where(tau < t1, v0 + a1 * u1, np.where(tau < t1 + tc, vc, vc + a3 * u3))
        done = tau >= t1 + tc + t3
        s = np.where(done, self.len_mm[i], np.minimum(s, self.len_mm[i]))
        v = np.where(done, v1, np.maximum(v, 0.0))
        return s, v

    # Evaluation ---------------------------------------------------------------------

    def locate(self, t_s: np.ndarray) -> np.ndarray:
        """Local row running at times ``t_s`` (a row owns ``[t_start, t_end)``; the end maps to the last row)."""
        i = np.searchsorted(self.t_end_s, np.asarray(t_s, dtype=float), side="right")
        return np.minimum(i, self.n - 1)

    def sample(self, t_s: float) -> Sample:
        """The commanded state ``t_s`` seconds after the timeline's start (clamped to [0, total]).

        Same values as :meth:`sample_many`, with a scalar fast path for the rows
        telemetry hits most (linear moves and stationary rows).
        """
        if self.n == 0:
            raise ValueError("empty timeline")
        t = min(max(float(t_s), 0.0), self.total_s)
        i = min(int(np.searchsorted(self.t_end_s, t, side="right")), self.n - 1)
        p = self.program
        r = self.start_row + i
        op = int(p.op[r])
        if op == MOVEJ:
            return self.sample_many(np.array([t]))[0]
        x1 = p.xyz_mm[r]
        wobj = p.wobj
        if op != MOVEL:
            dur = float(self.t_end_s[i] - self.t_start_s[i])
            prog = min(max((t - float(self.t_start_s[i])) / dur, 0.0), 1.0) if dur > 0 else 1.0
            return Sample(r, p.q_rad[r].copy(), x1.copy(), p.quat_wxyz[r].copy(), 0.0, False, 0.0, prog,
                          wobj[:3, :3] @ x1 + wobj[:3, 3], 0.0)
        s, v = self._profile_scalar(i, t - float(self.t_start_s[i]))
        if i == 0:
            q0, x0, quat0, s0 = self.first_from_q_rad, self.first_from_xyz_mm, self.first_from_quat_wxyz, self.s0_mm
        else:
            q0, x0, quat0, s0 = p.q_rad[r - 1], p.xyz_mm[r - 1], p.quat_wxyz[r - 1], 0.0
        d = x1 - x0
        L = math.sqrt(float(d @ d))
        f = min(max((s0 + s) / L, 0.0), 1.0) if L > 0 else 1.0
        xyz = x0 + f * d
        quat = nlerp_quat(quat0[None], p.quat_wxyz[r][None], np.array([f]))[0]
        flow = float(p.flow_mm3_mm[r])
        return Sample(r, q0 + f * (p.q_rad[r] - q0), xyz, quat, v, flow > 0, flow * v * self.flow_r, f,
                      wobj[:3, :3] @ xyz + wobj[:3, 3], s0 + s)

    def _profile_scalar(self, i: int, tau: float) -> tuple[float, float]:
        """:meth:`profile` for one row and one time, in plain floats."""
        a = self.accel_mm_s2
        v0, vc, v1 = float(self.v0_mm_s[i]), float(self.vc_mm_s[i]), float(self.v1_mm_s[i])
        t1, tc, t3 = float(self.t1_s[i]), float(self.tc_s[i]), float(self.t3_s[i])
        length = float(self.len_mm[i])
        if tau >= t1 + tc + t3:
            return length, v1
        tau = max(tau, 0.0)
        a1 = math.copysign(a, vc - v0) if vc != v0 else 0.0
        if tau < t1:
            return min(v0 * tau + 0.5 * a1 * tau * tau, length), max(v0 + a1 * tau, 0.0)
        s1 = v0 * t1 + 0.5 * a1 * t1 * t1
        if tau < t1 + tc:
            return min(s1 + vc * (tau - t1), length), vc
        u = tau - t1 - tc
        a3 = math.copysign(a, v1 - vc) if v1 != vc else 0.0
        return min(s1 + vc * tc + vc * u + 0.5 * a3 * u * u, length), max(vc + a3 * u, 0.0)

    def sample_many(self, t_s: np.ndarray) -> SampleBatch:
        """:meth:`sample` for an array of times, vectorised (joint moves evaluated per sample)."""
        if self.n == 0:
            raise ValueError("empty timeline")
        t = np.clip(np.asarray(t_s, dtype=float).reshape(-1), 0.0, self.total_s)
        p = self.program
        i = self.locate(t)
        rows = self.start_row + i
        tau = t - self.t_start_s[i]
        op = p.op[rows]
        q0, x0, quat0 = self.from_pose(i)
        # Default: hold the row's pose (non-motion rows, and ends of moves).
        q = p.q_rad[rows].copy()
        xyz = p.xyz_mm[rows].copy()
        quat = p.quat_wxyz[rows].copy()
        speed = np.zeros(len(t))
        s_full = np.zeros(len(t))
        dur = self.duration_s[i]
        progress = np.where(dur > 0, np.clip(tau / np.where(dur > 0, dur, 1.0), 0.0, 1.0), 1.0)
        lin = op == MOVEL
        if lin.any():
            il = i[lin]
            s, v = self.profile(il, tau[lin])
            s0 = np.where(il == 0, self.s0_mm, 0.0)
            L = self.row_length_mm(il)
            f = np.where(L > 0, np.clip((s0 + s) / np.where(L > 0, L, 1.0), 0.0, 1.0), 1.0)
            xyz[lin] = x0[lin] + f[:, None] * (p.xyz_mm[rows[lin]] - x0[lin])
            q[lin] = q0[lin] + f[:, None] * (p.q_rad[rows[lin]] - q0[lin])
            quat[lin] = nlerp_quat(quat0[lin], p.quat_wxyz[rows[lin]], f)
            speed[lin] = v
            s_full[lin] = s0 + s
            progress[lin] = f
        base = _apply(p.wobj, xyz)
        joint = np.flatnonzero(op == MOVEJ)
        if len(joint):
            self._sample_joint(i[joint], tau[joint], joint, q, xyz, quat, base, speed)
        flow = np.where(lin, p.flow_mm3_mm[rows] * speed * self.flow_r, 0.0)
        extruding = lin & (p.flow_mm3_mm[rows] > 0)
        return SampleBatch(rows, q, xyz, quat, speed, extruding, flow, progress, base, s_full)

    def _sample_joint(self, i: np.ndarray, tau: np.ndarray, where: np.ndarray, q: np.ndarray,
                      xyz: np.ndarray, quat: np.ndarray, base: np.ndarray, speed: np.ndarray) -> None:
        """Fill joint-move samples in place: Ruckig state, TCP by forward kinematics (speed by J*qdot
        approximated with a 0.1 ms finite difference of the FK)."""
        h = 1e-4
        qs = np.empty((2 * len(i), q.shape[1]))
        for k, (ii, tt) in enumerate(zip(i.tolist(), tau.tolist(), strict=True)):
            traj = self.joint_traj.get(ii)
            if traj is None or tt >= traj.duration:
                qs[2 * k] = qs[2 * k + 1] = self.program.q_rad[self.start_row + ii]
                continue
            pos, vel, _acc = traj.at_time(tt)
            qs[2 * k] = pos
            qs[2 * k + 1] = np.asarray(pos) + h * np.asarray(vel)
        T = np.asarray(self.robot.fk(qs))
        Tp = inv_T(self.program.wobj) @ T[0::2]
        q[where] = qs[0::2]
        base[where] = T[0::2, :3, 3]
        xyz[where] = Tp[:, :3, 3]
        quat[where] = quat_from_R(Tp[:, :3, :3])
        speed[where] = np.linalg.norm(T[1::2, :3, 3] - T[0::2, :3, 3], axis=-1) / h


def _apply(T: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """Points (N, 3) mapped by the rigid transform ``T``."""
    return xyz @ T[:3, :3].T + T[:3, 3]
