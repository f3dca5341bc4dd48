"""Checks a program before it runs: shapes, codes, finite values, sane speeds and set points, joint limits."""
from __future__ import annotations

from typing import Any

import numpy as np

from fabric.motion.program import MOVEJ, MOVEL, RETRACT, SET_TEMP, WAIT, WAIT_TEMP, Program
from fabric.wire.errors import UnreachableError, ValidationError

__all__ = ["validate_program"]


def validate_program(program: Program, robot: Any, *, max_temp_c: tuple[float, float] = (300.0, 120.0)) -> None:
    """Check a program before it runs: shapes and op codes, finite values, sane speeds, zones,
    flows, waits and set points (ValidationError), and every row's joints inside the robot's
    limits (UnreachableError naming the row, G-code line, joint and limit)."""
    if not isinstance(program, Program):
        raise ValidationError(f"expected a Program, got {type(program).__name__}", field="program")
    n = len(program)
    if n == 0:
        raise ValidationError("the program has no rows", field="program")
    op = program.op

    def bad(mask: np.ndarray, field_name: str, what: str) -> None:
        if mask.any():
            r = int(np.flatnonzero(mask)[0])
            g = int(program.gcode_line[r])
            raise ValidationError(f"row {r} (G-code line {g}): {field_name} {what}", field=field_name, row=r,
                                  gcode_line=g)

    bad(op > RETRACT, "op", "is not a known instruction")
    for name in ("q_rad", "xyz_mm", "quat_wxyz", "speed_mm_s", "vel_r", "zone_mm", "flow_mm3_mm", "value"):
        arr = getattr(program, name)
        bad(~np.isfinite(arr).reshape(n, -1).all(axis=1), name, "is not finite")
    if program.q_rad.shape[1] != len(np.asarray(robot.lower_rad)):
        raise ValidationError(f"program has {program.q_rad.shape[1]} joints, robot has {len(robot.lower_rad)}",
                              field="q_rad")
    bad(np.linalg.norm(program.quat_wxyz, axis=1) < 1e-6, "quat_wxyz", "is not a rotation")
    bad((op == MOVEL) & (program.speed_mm_s <= 0), "speed_mm_s", "must be > 0 on a linear move")
    bad((op == MOVEJ) & ((program.vel_r <= 0) | (program.vel_r > 1)), "vel_r", "must be in (0, 1] on a joint move")
    bad(program.zone_mm < 0, "zone_mm", "must be >= 0")
    bad(program.flow_mm3_mm < 0, "flow_mm3_mm", "must be >= 0")
    bad((op == WAIT) & (program.value < 0), "value", "(wait seconds) must be >= 0")
    temp = (op == SET_TEMP) | (op == WAIT_TEMP)
    bad(temp & ((program.aux < 0) | (program.aux > 1)), "aux", "(heater id) must be 0 (nozzle) or 1 (bed)")
    hi = np.where(program.aux == 1, max_temp_c[1], max_temp_c[0])
    bad(temp & ((program.value < 0) | (program.value > hi)), "value", "(set point) out of range")
    lo_l, up_l = np.asarray(robot.lower_rad, float), np.asarray(robot.upper_rad, float)
    out = (program.q_rad < lo_l - 1e-9) | (program.q_rad > up_l + 1e-9)
    if out.any():
        r, j = (int(v) for v in np.argwhere(out)[0])
        g = int(program.gcode_line[r])
        val = float(program.q_rad[r, j])
        lim = float(lo_l[j] if val < lo_l[j] else up_l[j])
        raise UnreachableError(f"row {r} (G-code line {g}): joint A{j + 1} at {np.degrees(val):.3f} deg is outside "
                               f"its limit {np.degrees(lim):.3f} deg", row=r, gcode_line=g, joint=j,
                               value_deg=float(np.degrees(val)), limit_deg=float(np.degrees(lim)),
                               reason="joint limit")
