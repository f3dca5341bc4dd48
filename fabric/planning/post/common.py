"""Shared helpers of the post-processors: row iteration, extruder transitions, angle conventions."""
from __future__ import annotations

from collections.abc import Iterator
from typing import TextIO

import numpy as np

from fabric.motion.program import MOVEL, Program
from fabric.robot.frames import R_from_quat
from fabric.wire.errors import ValidationError

__all__ = ["check_program", "check_six_axes", "row_blocks", "extrusion_rate", "max_extrusion_rate",
           "quat_to_rotvec", "R_to_zyx_deg", "quat_to_zyx_deg", "write_lines", "write_ascii"]

BLOCK_ROWS = 20_000     # rows formatted per write: output streams, memory stays flat
CHECK_ROWS = 1 << 18    # rows checked at once


def check_program(program: Program) -> None:
    """Refuse to export a program that is empty or has non-finite targets."""
    if not isinstance(program, Program):
        raise ValidationError(f"expected a Program, got {type(program).__name__}", field="program")
    if len(program) == 0:
        raise ValidationError("the program has no rows", field="program")
    for a, b in row_blocks(0, len(program), CHECK_ROWS):     # in blocks: a mapped program stays on disk
        motion = program.op[a:b] <= MOVEL
        for name in ("q_rad", "xyz_mm", "quat_wxyz"):
            arr = getattr(program, name)[a:b]
            # a row's sum is finite when all its values are (a huge finite sum may overflow: checked exactly below)
            suspect = ~np.isfinite(arr @ np.ones(arr.shape[1])) & motion
            if not suspect.any():
                continue
            bad = np.flatnonzero(suspect & ~np.isfinite(arr).all(axis=1))
            if len(bad):
                row = a + int(bad[0])
                raise ValidationError(f"row {row}: {name} is not finite", field=name, row=row,
                                      gcode_line=int(program.gcode_line[row]))
        program.release_pages(a, b)


def check_six_axes(program: Program, language: str) -> None:
    """Refuse a program of an arm that is not 6-axis in a language whose joint moves have six axes.

    RAPID's ``robax``, KRL's ``A1..A6`` and URScript's ``movej`` take six joints; a 7-axis arm
    (the Panda) exports as CSV."""
    if program.nq != 6:
        raise ValidationError(f"{language} takes the joints of a 6-axis arm, this program has {program.nq} "
                              "per row: export it as CSV", field="format", value=language, nq=program.nq)


def row_blocks(start: int, stop: int, size: int = BLOCK_ROWS) -> Iterator[tuple[int, int]]:
    """``[a, b)`` ranges covering ``[start, stop)``."""
    for a in range(start, stop, size):
        yield a, min(a + size, stop)


def max_extrusion_rate(program: Program) -> float:
    """The highest programmed volumetric rate (mm^3/s) of the program, at least 1e-9 (in blocks of rows)."""
    top = 0.0
    for a, b in row_blocks(0, len(program), CHECK_ROWS):
        top = max(top, float(extrusion_rate(program, a, b).max(initial=0.0)))
        program.release_pages(a, b)
    return max(top, 1e-9)


def extrusion_rate(program: Program, start: int = 0, stop: int | None = None) -> np.ndarray:
    """Programmed volumetric rate in mm^3/s of rows ``[start, stop)`` (all by default; flow per mm x speed;
    0 off)."""
    sl = slice(start, stop)
    rate = program.flow_mm3_mm[sl] * program.speed_mm_s[sl]
    return np.where(program.op[sl] == MOVEL, rate, 0.0)


def quat_to_rotvec(q_wxyz: np.ndarray) -> np.ndarray:
    """(N, 3) rotation vectors (axis * angle, rad) of unit quaternions (w, x, y, z)."""
    q = np.asarray(q_wxyz, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 0])
    scale = np.where(s > 1e-12, angle / np.maximum(s, 1e-300), 2.0)
    return q[..., 1:] * scale[..., None]


def R_to_zyx_deg(R: np.ndarray) -> np.ndarray:
    """(N, 3) KUKA ``A, B, C`` (deg): ``R = Rz(A) Ry(B) Rx(C)``."""
    R = np.asarray(R, dtype=float)
    b = np.arctan2(-R[..., 2, 0], np.hypot(R[..., 0, 0], R[..., 1, 0]))
    gimbal = np.hypot(R[..., 0, 0], R[..., 1, 0]) < 1e-12
    a = np.where(gimbal, np.arctan2(-R[..., 0, 1], R[..., 1, 1]), np.arctan2(R[..., 1, 0], R[..., 0, 0]))
    c = np.where(gimbal, 0.0, np.arctan2(R[..., 2, 1], R[..., 2, 2]))
    return np.degrees(np.stack([a, b, c], axis=-1))


def quat_to_zyx_deg(q_wxyz: np.ndarray) -> np.ndarray:
    """(N, 3) KUKA ``A, B, C`` (deg) of quaternions (w, x, y, z)."""
    return R_to_zyx_deg(R_from_quat(q_wxyz))


def write_lines(out: TextIO, lines: list[str]) -> None:
    if lines:
        out.write("\n".join(lines))
        out.write("\n")


def write_ascii(out: TextIO, text: bytes) -> None:
    """Write ASCII text formatted as bytes (``numtext``): as bytes to a stream that takes them
    (one with a ``write_bytes`` method, e.g. the export stream), decoded to a ``str`` otherwise."""
    write_bytes = getattr(out, "write_bytes", None)
    if write_bytes is not None:
        write_bytes(text)
    else:
        out.write(text.decode("ascii"))
