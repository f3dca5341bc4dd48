"""Universal Robots URScript post-processor: one ``def`` program of movej / movel in SI units.

Poses are ``p[x, y, z, rx, ry, rz]`` in metres and a rotation vector
(axis * angle, rad); every linear target is ``pose_trans(plate, p[...])`` with
``plate`` the plate frame in the robot base frame, so the numbers written are
the plate-frame targets. Joint moves use the planned joints (rad) at
``vel_r`` times ``joint_speed_rad_s``. Blends: ``r`` is the row's zone in
metres (0 = stop). The extruder is ``set_digital_out(0, ...)`` and
``set_analog_out(0, rate / flow_max)``; URScript outputs switch when the
interpreter reaches them (not path-synchronous), which with blends is at the
start of the previous move's blend; the extruder goes off before a joint move, a dwell,
a heater wait or a retraction (``walk.py``). Heaters: analog outputs 1 (nozzle / 300 C)
and 2 (bed / 150 C), waits on digital inputs 0 / 1; retraction: analog output
3 (length / 10 mm) and a pulse on digital output 1.
"""
from __future__ import annotations

from typing import TextIO

import numpy as np

from fabric.motion.program import MOVEL, Program
from fabric.planning.post.common import (
    check_program,
    check_six_axes,
    max_extrusion_rate,
    quat_to_rotvec,
    write_ascii,
    write_lines,
)
from fabric.planning.post.numtext import Column, FixedColumn, format_rows
from fabric.planning.post.walk import (
    Block,
    Event,
    ExtruderOff,
    ExtruderOn,
    ExtruderRate,
    JointMove,
    LinearMove,
    LinearRun,
    Retract,
    RowWalker,
    SetTemp,
    Wait,
    WaitTemp,
    heater_index,
)
from fabric.robot.frames import quat_from_R
from fabric.wire.errors import ValidationError

__all__ = ["write_urscript"]

_TEMP_SCALE = {0: 300.0, 1: 150.0}


def _pose_m(T: np.ndarray) -> str:
    rv = quat_to_rotvec(quat_from_R(T[:3, :3])[None])[0]
    x, y, z = T[:3, 3] / 1000.0
    return f"p[{x:.6f},{y:.6f},{z:.6f},{rv[0]:.6f},{rv[1]:.6f},{rv[2]:.6f}]"


def write_urscript(program: Program, out: TextIO, *, name: str = "am_print", tool_T: np.ndarray | None = None,
                   joint_speed_rad_s: float = 1.0, accel_m_s2: float = 1.2) -> int:
    """Write ``program`` as a URScript program to ``out``; returns the number of targets."""
    check_program(program)
    check_six_axes(program, "URScript")
    if not name.isidentifier():
        raise ValidationError("URScript program name must be an identifier", field="name", value=name)
    if not (joint_speed_rad_s > 0 and accel_m_s2 > 0):
        raise ValidationError("speeds and accelerations must be positive", field="joint_speed_rad_s")
    tool = np.eye(4) if tool_T is None else np.asarray(tool_T, dtype=float)
    flow_max = max_extrusion_rate(program)
    write_lines(out, [f"def {name}():", f"  # am-fabric URScript export: {int((program.op <= MOVEL).sum())} targets",
                      f"  set_tcp({_pose_m(tool)})", f"  plate = {_pose_m(program.wobj)}",
                      "  set_digital_out(0, False)", "  set_analog_out(0, 0.0)"])
    fmt = _Formatter(program, flow_max, joint_speed_rad_s, accel_m_s2)
    lines: list[str] = []
    for ev in RowWalker(program, runs=True).walk():
        if isinstance(ev, (Block, LinearRun)):
            write_lines(out, lines)
            lines = []
        if isinstance(ev, LinearRun):
            write_ascii(out, fmt.run(ev))
        else:
            fmt.event(ev, lines)
    write_lines(out, lines)
    write_lines(out, ["  set_digital_out(0, False)", "  set_analog_out(0, 0.0)", "end", f"{name}()"])
    return int((program.op <= MOVEL).sum())


class _Formatter:
    """Formats the walker's events as URScript (SI units: metres, radians, seconds)."""

    def __init__(self, program: Program, flow_max: float, joint_speed_rad_s: float, accel_m_s2: float) -> None:
        self.p, self.flow_max = program, flow_max
        self.joint_speed_rad_s, self.accel_m_s2 = joint_speed_rad_s, accel_m_s2

    def event(self, ev: Event, lines: list[str]) -> None:
        p = self.p
        if isinstance(ev, Block):
            # rotation vectors of the block's rows
            self.base = ev.start
            self.rotvec = quat_to_rotvec(p.quat_wxyz[ev.start:ev.stop])
        elif isinstance(ev, LinearMove):
            self._linear(ev, lines)
        elif isinstance(ev, JointMove):
            q = ",".join(f"{v:.6f}" for v in p.q_rad[ev.row])
            v = self.joint_speed_rad_s * float(p.vel_r[ev.row] or 1.0)
            lines.append(f"  movej([{q}], a=1.4, v={v:.4f})")
        elif isinstance(ev, ExtruderOff):
            lines += ["  set_digital_out(0, False)", "  set_analog_out(0, 0.0)"]
        elif isinstance(ev, Wait):
            lines.append(f"  sleep({ev.duration_s:.3f})")
        elif isinstance(ev, SetTemp):
            heater = heater_index(ev.heater)
            lines.append(f"  set_analog_out({1 + heater}, {ev.temp_c / _TEMP_SCALE[heater]:.5f})")
        elif isinstance(ev, WaitTemp):
            lines += [f"  while not get_digital_in({heater_index(ev.heater)}):", "    sync()", "  end"]
        elif isinstance(ev, Retract):
            lines += [f"  set_analog_out(3, {ev.length_mm / 10.0:.5f})",
                      "  set_digital_out(1, True)", "  sleep(0.1)", "  set_digital_out(1, False)"]

    def run(self, run: LinearRun) -> bytes:
        """The ``movel`` lines of a run of plain linear moves as columns (the same text as :meth:`_linear`)."""
        p, rows, k = self.p, slice(run.start, run.stop), slice(run.start - self.base, run.stop - self.base)
        xyz_m, rotvec = p.xyz_mm[rows] / 1000.0, self.rotvec[k]
        columns: list[Column] = [b"  movel(pose_trans(plate, p["]
        for j, col in enumerate([*xyz_m.T, *rotvec.T]):
            columns += [b",", FixedColumn(col, 6)] if j else [FixedColumn(col, 6)]
        columns += [f"]), a={self.accel_m_s2:.3f}, v=".encode(), FixedColumn(p.speed_mm_s[rows] / 1000.0, 5),
                    b", r=", FixedColumn(p.zone_mm[rows] / 1000.0, 5), b")  # ", FixedColumn(p.gcode_line[rows], 0)]
        return format_rows(columns, sep=b"")

    def _linear(self, ev: LinearMove, lines: list[str]) -> None:
        p, i = self.p, ev.row
        sw = ev.extruder
        if isinstance(sw, (ExtruderOn, ExtruderRate)):
            lines.append(f"  set_analog_out(0, {sw.rate_mm3_s / self.flow_max:.5f})")
            if isinstance(sw, ExtruderOn):
                lines.append("  set_digital_out(0, True)")
        elif isinstance(sw, ExtruderOff):
            lines += ["  set_digital_out(0, False)", "  set_analog_out(0, 0.0)"]
        x, y, z = p.xyz_mm[i] / 1000.0
        rx, ry, rz = self.rotvec[i - self.base]
        lines.append(f"  movel(pose_trans(plate, p[{x:.6f},{y:.6f},{z:.6f},{rx:.6f},{ry:.6f},{rz:.6f}]), "
                     f"a={self.accel_m_s2:.3f}, v={p.speed_mm_s[i] / 1000.0:.5f}, "
                     f"r={p.zone_mm[i] / 1000.0:.5f})  # {p.gcode_line[i]}")
