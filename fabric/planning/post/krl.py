"""KUKA KRL post-processor: a ``.src`` program (PTP / LIN) and its ``.dat`` data list.

Frames: ``$BASE`` is the plate frame in the robot base frame and ``$TOOL`` the
TCP in the flange frame, both declared in the ``.dat`` as ``FRAME`` values
(KUKA ``A, B, C`` = rotations about z, y, x: ``R = Rz(A) Ry(B) Rx(C)``, deg);
every ``LIN`` target is in the plate frame. Approach and return are ``PTP``
moves on the planned joints (``$VEL_AXIS`` from the row's velocity ratio).

Extruder and heaters, as signals the integrator maps: ``$OUT[1]`` extruder
on/off and ``$ANOUT[1]`` volumetric rate / ``AM_FLOW_MAX`` switched with
``TRIGGER WHEN DISTANCE=0`` (at the start of the move, path-synchronous), and switched off
plainly before a joint move, a dwell, a heater wait or a retraction (``walk.py``);
``$ANOUT[2]`` / ``$ANOUT[3]`` nozzle / bed set point divided by 300 / 150 deg C,
``WAIT FOR $IN[1]`` / ``$IN[2]`` heater at temperature; retraction writes the
length / 10 mm to ``$ANOUT[4]`` and pulses ``$OUT[2]``.
"""
from __future__ import annotations

import itertools
from typing import TextIO

import numpy as np

from fabric.motion.program import MOVEL, Program
from fabric.planning.post.common import (
    R_to_zyx_deg,
    check_program,
    check_six_axes,
    max_extrusion_rate,
    quat_to_zyx_deg,
    write_ascii,
    write_lines,
)
from fabric.planning.post.numtext import ChoiceColumn, Column, FixedColumn, format_rows
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
from fabric.wire.errors import ValidationError

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
    check_six_axes(program, "KRL")
    if not name.isidentifier() or len(name) > 24:
        raise ValidationError("KRL program name must be an identifier of <= 24 chars", field="name", value=name)
    tool = np.eye(4) if tool_T is None else np.asarray(tool_T, dtype=float)
    flow_max = max_extrusion_rate(program)
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
    fmt = _Formatter(program, flow_max)
    lines: list[str] = []
    for ev in RowWalker(program, runs=True).walk():
        if isinstance(ev, (Block, LinearRun)):
            write_lines(src, lines)
            lines = []
        if isinstance(ev, LinearRun):
            fmt.run(ev, src)
        else:
            fmt.event(ev, lines)
    write_lines(src, lines)
    write_lines(src, ["  $OUT[1]=FALSE", "  $ANOUT[1]=0.0", "END"])
    return int((program.op <= MOVEL).sum())


_TRIGGER = "  TRIGGER WHEN DISTANCE=0 DELAY=0 DO "


class _Formatter:
    """Formats the walker's events as KRL; keeps the modal ``$VEL.CP`` and ``$APO.CDIS`` written last."""

    def __init__(self, program: Program, flow_max: float) -> None:
        self.p, self.flow_max = program, flow_max
        self.vel_m_s = -1.0
        self.zone_mm = -1.0

    def event(self, ev: Event, lines: list[str]) -> None:
        p = self.p
        if isinstance(ev, Block):
            # KUKA A, B, C and joints in degrees of the block's rows
            self.base = ev.start
            self.abc = quat_to_zyx_deg(p.quat_wxyz[ev.start:ev.stop])
            self.q_deg = np.degrees(p.q_rad[ev.start:ev.stop])
        elif isinstance(ev, LinearMove):
            self._linear(ev, lines)
        elif isinstance(ev, JointMove):
            pct = max(1, min(100, int(round(100 * float(p.vel_r[ev.row] or 1.0)))))
            q = self.q_deg[ev.row - self.base]
            axes = ",".join(f"A{j + 1} {q[j]:.4f}" for j in range(len(q)))
            lines += [f"  $VEL_AXIS[1]={pct}", f"  PTP {{{axes}}}"]
        elif isinstance(ev, ExtruderOff):
            lines += ["  $OUT[1]=FALSE", "  $ANOUT[1]=0.0"]
        elif isinstance(ev, Wait):
            lines.append(f"  WAIT SEC {ev.duration_s:.3f}")
        elif isinstance(ev, SetTemp):
            heater = heater_index(ev.heater)
            lines.append(f"  $ANOUT[{2 + heater}]={ev.temp_c / _TEMP_SCALE[heater]:.5f}")
        elif isinstance(ev, WaitTemp):
            lines.append(f"  WAIT FOR $IN[{1 + heater_index(ev.heater)}]")
        elif isinstance(ev, Retract):
            lines += [f"  $ANOUT[4]={ev.length_mm / 10.0:.5f}", "  PULSE($OUT[2],TRUE,0.1)"]

    def run(self, run: LinearRun, out: TextIO) -> None:
        """A run of plain linear moves: where the speed or zone changes a row goes through :meth:`_linear`
        (which writes ``$VEL.CP`` / ``$APO.CDIS`` and keeps them), the rows between as columns."""
        p = self.p
        speed, zone = p.speed_mm_s[run.start:run.stop], p.zone_mm[run.start:run.stop]
        changes = np.flatnonzero((speed[1:] != speed[:-1]) | (zone[1:] != zone[:-1])) + 1
        cuts = [0, *changes.tolist(), run.stop - run.start]
        for a, b in itertools.pairwise(cuts):
            lines: list[str] = []
            self._linear(LinearMove(run.start + a), lines)
            write_lines(out, lines)
            if b > a + 1:
                write_ascii(out, self._lin_rows(run.start + a + 1, run.start + b))

    def _lin_rows(self, start: int, stop: int) -> bytes:
        """``LIN`` lines of rows ``[start, stop)`` as columns (the same text as :meth:`_linear` writes)."""
        p, rows, k = self.p, slice(start, stop), slice(start - self.base, stop - self.base)
        xyz, abc = p.xyz_mm[rows], self.abc[k]
        columns: list[Column] = [b"  LIN {X ", FixedColumn(xyz[:, 0], 3), b",Y ", FixedColumn(xyz[:, 1], 3),
                                 b",Z ", FixedColumn(xyz[:, 2], 3), b",A ", FixedColumn(abc[:, 0], 4),
                                 b",B ", FixedColumn(abc[:, 1], 4), b",C ", FixedColumn(abc[:, 2], 4), b"}",
                                 ChoiceColumn(p.zone_mm[rows] > 0, [b"", b" C_DIS"]), b" ; ",
                                 FixedColumn(p.gcode_line[rows], 0)]
        return format_rows(columns, sep=b"")

    def _linear(self, ev: LinearMove, lines: list[str]) -> None:
        p, i, k = self.p, ev.row, ev.row - self.base
        v = float(p.speed_mm_s[i]) / 1000.0
        if v != self.vel_m_s:
            lines.append(f"  $VEL.CP={v:.5f}")
            self.vel_m_s = v
        z = float(p.zone_mm[i])
        if z > 0 and z != self.zone_mm:
            lines.append(f"  $APO.CDIS={z:.3f}")
            self.zone_mm = z
        sw = ev.extruder
        if isinstance(sw, (ExtruderOn, ExtruderRate)):
            lines.append(f"{_TRIGGER}$ANOUT[1]={sw.rate_mm3_s / self.flow_max:.5f}")
            if isinstance(sw, ExtruderOn):
                lines.append(f"{_TRIGGER}$OUT[1]=TRUE")
        elif isinstance(sw, ExtruderOff):
            lines += [f"{_TRIGGER}$OUT[1]=FALSE", f"{_TRIGGER}$ANOUT[1]=0.0"]
        x, y, zz = p.xyz_mm[i]
        a, b, c = self.abc[k]
        lines.append(f"  LIN {{X {x:.3f},Y {y:.3f},Z {zz:.3f},A {a:.4f},B {b:.4f},C {c:.4f}}}"
                     f"{' C_DIS' if z > 0 else ''} ; {p.gcode_line[i]}")
