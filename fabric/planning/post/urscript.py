"""Universal Robots URScript post-processor: one ``def`` program of movej / movel in SI units.

Poses are ``p[x, y, z, rx, ry, rz]`` in metres and a rotation vector
(axis * angle, rad); every linear target is ``pose_trans(plate, p[...])`` with
``plate`` the plate frame in the robot base frame, so the numbers written are
the plate-frame targets. Joint moves use the planned joints (rad) at
``vel_r`` times ``joint_speed_rad_s``. Blends: ``r`` is the row's zone in
metres (0 = stop). The extruder is ``set_digital_out(0, ...)`` and
``set_analog_out(0, rate / flow_max)``; URScript outputs switch when the
interpreter reaches them (not path-synchronous), which with blends is at the
start of the previous move's blend. Heaters: analog outputs 1 (nozzle / 300 C)
and 2 (bed / 150 C), waits on digital inputs 0 / 1; retraction: analog output
3 (length / 10 mm) and a pulse on digital output 1.
"""
from __future__ import annotations

from typing import TextIO

import numpy as np

from fabric.errors import ValidationError
from fabric.planning.post.common import check_program, extrusion_rate, quat_to_rotvec, row_blocks, write_lines
from fabric.robot.frames import quat_from_R
from fabric.motion.program import BED, MOVEJ, MOVEL, RETRACT, SET_TEMP, WAIT, WAIT_TEMP, Program

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
    if not name.isidentifier():
        raise ValidationError("URScript program name must be an identifier", field="name", value=name)
    if not (joint_speed_rad_s > 0 and accel_m_s2 > 0):
        raise ValidationError("speeds and accelerations must be positive", field="joint_speed_rad_s")
    tool = np.eye(4) if tool_T is None else np.asarray(tool_T, dtype=float)
    rate = extrusion_rate(program)
    flow_max = float(max(rate.max(initial=0.0), 1e-9))
    write_lines(out, [f"def {name}():", f"  # am-fabric URScript export: {int((program.op <= MOVEL).sum())} targets",
                      f"  set_tcp({_pose_m(tool)})", f"  plate = {_pose_m(program.wobj)}",
                      "  set_digital_out(0, False)", "  set_analog_out(0, 0.0)"])
    on, cur = False, -1.0
    for a, b in row_blocks(0, len(program)):
        rv = quat_to_rotvec(program.quat_wxyz[a:b])
        lines: list[str] = []
        for i in range(a, b):
            k, op = i - a, int(program.op[i])
            if op == MOVEJ:
                if on:
                    lines += ["  set_digital_out(0, False)", "  set_analog_out(0, 0.0)"]
                    on = False
                q = ",".join(f"{v:.6f}" for v in program.q_rad[i])
                v = joint_speed_rad_s * float(program.vel_r[i] or 1.0)
                lines.append(f"  movej([{q}], a=1.4, v={v:.4f})")
            elif op == MOVEL:
                r = round(float(rate[i]), 3)
                if r > 0 and (not on or r != cur):
                    lines.append(f"  set_analog_out(0, {r / flow_max:.5f})")
                    if not on:
                        lines.append("  set_digital_out(0, True)")
                    on, cur = True, r
                elif r <= 0 and on:
                    lines += ["  set_digital_out(0, False)", "  set_analog_out(0, 0.0)"]
                    on = False
                x, y, z = program.xyz_mm[i] / 1000.0
                lines.append(f"  movel(pose_trans(plate, p[{x:.6f},{y:.6f},{z:.6f},{rv[k, 0]:.6f},{rv[k, 1]:.6f},"
                             f"{rv[k, 2]:.6f}]), a={accel_m_s2:.3f}, v={program.speed_mm_s[i] / 1000.0:.5f}, "
                             f"r={program.zone_mm[i] / 1000.0:.5f})  # {program.gcode_line[i]}")
            elif op == WAIT:
                lines.append(f"  sleep({float(program.value[i]):.3f})")
            elif op in (SET_TEMP, WAIT_TEMP):
                heater = int(program.aux[i] == BED)
                lines.append(f"  set_analog_out({1 + heater}, {float(program.value[i]) / _TEMP_SCALE[heater]:.5f})")
                if op == WAIT_TEMP:
                    lines += [f"  while not get_digital_in({heater}):", "    sync()", "  end"]
            elif op == RETRACT:
                lines += [f"  set_analog_out(3, {float(program.value[i]) / 10.0:.5f})",
                          "  set_digital_out(1, True)", "  sleep(0.1)", "  set_digital_out(1, False)"]
        write_lines(out, lines)
    write_lines(out, ["  set_digital_out(0, False)", "  set_analog_out(0, 0.0)", "end", f"{name}()"])
    return int((program.op <= MOVEL).sum())
