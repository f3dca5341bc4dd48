"""CSV export: one row per target (TCP in the plate frame, orientation, joints, speed, extrusion, time)."""
from __future__ import annotations

from typing import TextIO

import numpy as np

from fabric.planning.post.common import check_program, row_blocks
from fabric.motion.program import MOVEL, Program

__all__ = ["write_csv", "CSV_COLUMNS"]

CSV_COLUMNS = ["gcode_line", "x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz",
               "q1_deg", "q2_deg", "q3_deg", "q4_deg", "q5_deg", "q6_deg", "speed_mm_s", "extrude", "t_s"]
_FMT = "%d,%.4f,%.4f,%.4f,%.7f,%.7f,%.7f,%.7f,%.5f,%.5f,%.5f,%.5f,%.5f,%.5f,%.3f,%d,%s"


def write_csv(program: Program, out: TextIO, t_end_s: np.ndarray | None = None) -> int:
    """Write the targets (MOVEJ / MOVEL rows) of ``program``; returns the number of rows written.

    ``t_end_s`` (one per program row, e.g. ``Timeline.t_end_s``) gives the time
    the robot reaches each target; without it the ``t_s`` column is empty.
    """
    check_program(program)
    if t_end_s is not None and len(t_end_s) != len(program):
        raise ValueError(f"t_end_s has {len(t_end_s)} rows, the program {len(program)}")
    out.write(",".join(CSV_COLUMNS) + "\n")
    n = 0
    for a, b in row_blocks(0, len(program)):
        idx = np.flatnonzero(program.op[a:b] <= MOVEL) + a
        if len(idx) == 0:
            continue
        q = np.degrees(program.q_rad[idx])
        ext = (program.flow_mm3_mm[idx] > 0).astype(int)
        t = [f"{v:.4f}" for v in t_end_s[idx]] if t_end_s is not None else [""] * len(idx)
        rows = zip(program.gcode_line[idx].tolist(), *program.xyz_mm[idx].T.tolist(),
                   *program.quat_wxyz[idx].T.tolist(), *q[:, :6].T.tolist(),
                   program.speed_mm_s[idx].tolist(), ext.tolist(), t)
        out.write("\n".join(_FMT % r for r in rows) + "\n")
        n += len(idx)
    return n
