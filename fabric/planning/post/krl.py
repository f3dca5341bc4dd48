"""KUKA KRL post-processor: a ``.src`` program (PTP / LIN) and its ``.dat`` data list.

Frames: ``$BASE`` is the plate frame in the robot base frame and ``$TOOL`` the
TCP in the flange frame, both declared in the ``.dat`` as ``FRAME`` values
(KUKA ``A, B, C`` = rotations about z, y, x: ``R = Rz(A) Ry(B) Rx(C)``, deg);
every ``LIN`` target is in the plate frame. Approach and return are ``PTP``
moves on the planned joints (``$VEL_AXIS`` from the row's velocity ratio).

Extruder and heaters, as signals the integrator maps: ``$OUT[1]`` extruder
on/off and ``$ANOUT[1]`` volumetric rate / ``AM_FLOW_MAX`` switched with
``TRIGGER WHEN DISTANCE=0`` (at the start of the move, path-synchronous);
``$ANOUT[2]`` / ``$ANOUT[3]`` nozzle / bed set point divided by 300 / 150 deg C,
``WAIT FOR $IN[1]`` / ``$IN[2]`` heater at temperature; retraction writes the
length / 10 mm to ``$ANOUT[4]`` and pulses ``$OUT[2]``.
"""
from __future__ import annotations

from typing import TextIO

import numpy as np

from fabric.errors import ValidationError
from fabric.planning.post.common import (check_program, extrusion_rate, quat_to_zyx_deg, row_blocks,
                                         write_lines, R_to_zyx_deg)
from fabric.motion.program import BED, MOVEJ, MOVEL, RETRACT, SET_TEMP, WAIT, WAIT_TEMP, Program

__all__ = ["write_krl"]

_TEMP_SCALE = {0: 300.0, 1: 150.0}


def _frame(T: np.ndarray) -> str:
    abc = R_to_zyx_deg(T[:3, :3])
    x, y, z = T[:3, 3]
    return f"{{X {x:.3f},Y {y:.3f},Z {z:.3f},A {abc[0]:.4f},B {abc[1]:.4f},C {abc[2]:.4f}}}"


def write_krl(program: Program, src: TextIO, dat: TextIO | None, *, name: str = "am_print",
              tool_T: np.ndarray | None = None) -> int:
    """Write ``program`` as KRL (``name.src`` to ``src``, ``name.dat`` to ``dat``); returns the target count.

    With ``dat=None`` the frames are written inline in the ``.src`` (one
    self-contained file, e.g. for a single download).
    """
    check_program(program)
    if not name.isidentifier() or len(name) > 24:
        raise ValidationError("KRL program name must be an identifier of <= 24 chars", field="name", value=name)
    tool = np.eye(4) if tool_T is None else np.asarray(tool_T, dtype=float)
    rate = extrusion_rate(program)
    flow_max = float(max(rate.max(initial=0.0), 1e-9))
    if dat is not None:
        write_lines(dat, ["&ACCESS RVP", "&REL 1", f"DEFDAT {name}",
                          f"  DECL FRAME AM_BASE={_frame(program.wobj)}",
                          f"  DECL FRAME AM_TOOL={_frame(tool)}",
                          f"  DECL REAL AM_FLOW_MAX={flow_max:.4f}", "ENDDAT"])
    base, tcp = ("AM_BASE", "AM_TOOL") if dat is not None else (_frame(program.wobj), _frame(tool))
    write_lines(src, ["&ACCESS RVP", "&REL 1", f"DEF {name}( )",
                      f"  ; am-fabric KRL export: {int((program.op <= MOVEL).sum())} targets",
                      f"  $BASE={base}", f"  $TOOL={tcp}", "  $OUT[1]=FALSE", "  $ANOUT[1]=0.0",
                      "  $ACC.CP=2.0", "  $ORI_TYPE=#VAR"])
    on, cur_rate, cur_vel, cur_zone = False, -1.0, -1.0, -1.0
    for a, b in row_blocks(0, len(program)):
        abc = quat_to_zyx_deg(program.quat_wxyz[a:b])
        qd = np.degrees(program.q_rad[a:b])
        lines: list[str] = []
        for i in range(a, b):
            k, op = i - a, int(program.op[i])
            if op == MOVEJ:
                if on:
                    lines += ["  $OUT[1]=FALSE", "  $ANOUT[1]=0.0"]
                    on = False
                pct = max(1, min(100, int(round(100 * float(program.vel_r[i] or 1.0)))))
                axes = ",".join(f"A{j + 1} {qd[k, j]:.4f}" for j in range(qd.shape[1]))
                lines += [f"  $VEL_AXIS[1]={pct}", f"  PTP {{{axes}}}"]
            elif op == MOVEL:
                v = float(program.speed_mm_s[i]) / 1000.0
                if v != cur_vel:
                    lines.append(f"  $VEL.CP={v:.5f}")
                    cur_vel = v
                z = float(program.zone_mm[i])
                if z > 0 and z != cur_zone:
                    lines.append(f"  $APO.CDIS={z:.3f}")
                    cur_zone = z
                r = round(float(rate[i]), 3)
                if r > 0 and (not on or r != cur_rate):
                    lines.append(f"  TRIGGER WHEN DISTANCE=0 DELAY=0 DO $ANOUT[1]={r / flow_max:.5f}")
                    if not on:
                        lines.append("  TRIGGER WHEN DISTANCE=0 DELAY=0 DO $OUT[1]=TRUE")
                    on, cur_rate = True, r
                elif r <= 0 and on:
                    lines += ["  TRIGGER WHEN DISTANCE=0 DELAY=0 DO $OUT[1]=FALSE",
                              "  TRIGGER WHEN DISTANCE=0 DELAY=0 DO $ANOUT[1]=0.0"]
                    on = False
                x, y, zz = program.xyz_mm[i]
                lines.append(f"  LIN {{X {x:.3f},Y {y:.3f},Z {zz:.3f},A {abc[k, 0]:.4f},B {abc[k, 1]:.4f},"
                             f"C {abc[k, 2]:.4f}}}{' C_DIS' if z > 0 else ''} ; {program.gcode_line[i]}")
            elif op == WAIT:
                lines.append(f"  WAIT SEC {float(program.value[i]):.3f}")
            elif op in (SET_TEMP, WAIT_TEMP):
                heater = int(program.aux[i] == BED)
                lines.append(f"  $ANOUT[{2 + heater}]={float(program.value[i]) / _TEMP_SCALE[heater]:.5f}")
                if op == WAIT_TEMP:
                    lines.append(f"  WAIT FOR $IN[{1 + heater}]")
            elif op == RETRACT:
                lines += [f"  $ANOUT[4]={float(program.value[i]) / 10.0:.5f}", "  PULSE($OUT[2],TRUE,0.1)"]
        write_lines(src, lines)
    write_lines(src, ["  $OUT[1]=FALSE", "  $ANOUT[1]=0.0", "END"])
    return int((program.op <= MOVEL).sum())
