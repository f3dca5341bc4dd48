"""CSV export: one row per target (TCP in the plate frame, orientation, joints, speed, extrusion, time)."""
from __future__ import annotations

from typing import Protocol, TextIO

import numpy as np

from fabric.ahead import ordered_map
from fabric.motion.program import MOVEL, Program
from fabric.planning.post.common import check_program, row_blocks, write_ascii
from fabric.planning.post.numtext import FixedColumn, format_rows

__all__ = ["write_csv", "csv_rows", "csv_columns", "CSV_COLUMNS", "RowTimes"]


def csv_columns(nq: int = 6) -> list[str]:
    """The header of an arm with ``nq`` joints: ``q1_deg`` .. ``q<nq>_deg`` between the pose and the speed."""
    return (["gcode_line", "x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz"]
            + [f"q{j + 1}_deg" for j in range(nq)] + ["speed_mm_s", "extrude", "t_s"])


CSV_COLUMNS = csv_columns(6)      # the header of a 6-axis arm
CSV_BLOCK_ROWS = 50_000      # rows formatted at once (measured fastest of 4k-50k; a block's bytes stay ~7 MB)


class RowTimes(Protocol):
    """Times by row, indexed by arrays of rows (an array, or times still being computed that wait for their rows)."""

    def __len__(self) -> int: ...

    def __getitem__(self, rows: np.ndarray) -> np.ndarray: ...


def write_csv(program: Program, out: TextIO, t_end_s: np.ndarray | RowTimes | None = None) -> int:
    """Write the targets (MOVEJ / MOVEL rows) of ``program``; returns the number of rows written.

    ``t_end_s`` (one per program row, e.g. ``Timeline.t_end_s``) gives the time
    the robot reaches each target; without it the ``t_s`` column is empty.
    """
    check_program(program)
    if t_end_s is not None and len(t_end_s) != len(program):
        raise ValueError(f"t_end_s has {len(t_end_s)} rows, the program {len(program)}")
    out.write(",".join(csv_columns(program.nq)) + "\n")
    blocks = (np.flatnonzero(program.op[a:b] <= MOVEL) + a for a, b in row_blocks(0, len(program), CSV_BLOCK_ROWS))
    n = 0
    for idx, text in ordered_map(lambda idx: (idx, csv_rows(program, idx, t_end_s)), (b for b in blocks if len(b))):
        write_ascii(out, text)        # blocks formatted ahead on a second core, written in order
        n += len(idx)
        program.release_pages(0, int(idx[0]))      # a program mapped from files: the rows written go
    return n


def csv_rows(program: Program, idx: np.ndarray, t_end_s: np.ndarray | RowTimes | None = None) -> bytes:
    """The CSV text of rows ``idx`` (vectorised: the characters ``%.<d>f`` would write)."""
    q_deg = np.degrees(program.q_rad[idx])
    xyz, quat = program.xyz_mm[idx], program.quat_wxyz[idx]
    columns: list[FixedColumn | bytes] = [FixedColumn(program.gcode_line[idx], 0)]
    columns += [FixedColumn(xyz[:, j], 4) for j in range(3)]
    columns += [FixedColumn(quat[:, j], 7) for j in range(4)]
    columns += [FixedColumn(q_deg[:, j], 5) for j in range(q_deg.shape[1])]
    columns += [FixedColumn(program.speed_mm_s[idx], 3),
                FixedColumn((program.flow_mm3_mm[idx] > 0).astype(np.int64), 0),
                FixedColumn(t_end_s[idx], 4) if t_end_s is not None else b""]
    return format_rows(columns)
