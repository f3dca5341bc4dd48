"""What the chunks planned so far add up to: their reach (counts by reason, the first unreachable target) and
their figures (moves, targets, volume, path, lifts), and what assembling one chunk found besides its rows."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabric.gcode import Toolpath
from fabric.motion.program import MOVEL, PRINT, Program
from fabric.planning.report import UNREACHABLE_CODES, Reachability

__all__ = ["Assembled", "Reach", "Totals"]


@dataclass
class Assembled:
    """What assembling a chunk found besides its rows (``axis``: the nozzle axis of every row, plate frame,
    from the tip up the nozzle, for a multi-axis toolpath; None for planar G-code)."""

    print_rows: int
    lifts: int
    fan_events: int
    approach_speed_mm_s: float
    leading_dropped: int
    axis: np.ndarray | None = None



class Reach:
    """The reachability of the chunks so far (counts by reason and by joint at fault, the first unreachable
    target)."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}
        self.ok = self.n = 0
        self.first: tuple[int, str] | None = None
        self.first_row = -1
        self.by_joint: dict[str, int] = {}

    def add(self, rep: Reachability, motion: np.ndarray, base: int) -> None:
        for reason, k in rep.counts.items():
            self.counts[reason] = self.counts.get(reason, 0) + k
        for joint, k in rep.by_joint.items():
            self.by_joint[joint] = self.by_joint.get(joint, 0) + k
        st = rep.status[motion]
        self.n += len(st)
        self.ok += int(len(st) - np.count_nonzero(np.isin(st, UNREACHABLE_CODES)))
        if self.first is None and rep.first_unreachable is not None:
            self.first, self.first_row = rep.first_unreachable, base + rep.first_unreachable_row

    def report(self, status: np.ndarray, rot_deg: np.ndarray) -> Reachability:
        return Reachability(status=status, rot_deg=rot_deg, feasible_r=self.ok / self.n if self.n else 1.0,
                            counts=self.counts, first_unreachable=self.first, first_unreachable_row=self.first_row,
                            by_joint=dict(sorted(self.by_joint.items())))


@dataclass
class Totals:
    """The figures of the chunks so far (see :class:`PlanStats`)."""

    moves: int = 0
    targets: int = 0
    print_rows: int = 0
    lifts: int = 0
    fan_events: int = 0
    leading_dropped: int = 0
    split_rows: int = 0              # rows added splitting linear moves (refine.py)
    approach_speed_mm_s: float = 0.0
    volume_mm3: float = 0.0
    path_mm: float = 0.0
    print_mm: float = 0.0
    first_layer_z_mm: float = float("inf")     # the lowest extruding nozzle height of layer 1 (plate frame)
    second_layer_z_mm: float = float("inf")    # ... of layer 2 (envelope.floating_warning)
    last_xyz: np.ndarray | None = None

    def add(self, prog: Program, tp: Toolpath, asm: Assembled, first: bool) -> None:
        xyz = prog.xyz_mm
        step = np.zeros_like(xyz)
        np.subtract(xyz[1:], xyz[:-1], out=step[1:])
        if self.last_xyz is not None and len(xyz):
            step[0] = xyz[0] - self.last_xyz         # the chunk's first move starts where the last chunk ended
        d = np.sqrt(np.einsum("ij,ij->i", step, step))
        del step
        lin = prog.op == MOVEL
        pm = (prog.section == PRINT) & lin
        extruding = lin & (prog.flow_mm3_mm > 0)
        self.volume_mm3 += float(np.dot(prog.flow_mm3_mm[lin], d[lin]))
        self.path_mm += float(d[pm].sum())
        self.print_mm += float(d[pm & extruding].sum())
        self._first_layers(xyz[:, 2], extruding, prog.layer)
        self.targets += int(np.count_nonzero(prog.op <= MOVEL))
        self.moves += len(tp)
        self.print_rows += asm.print_rows
        self.lifts += asm.lifts
        self.fan_events += asm.fan_events
        if first:
            self.leading_dropped, self.approach_speed_mm_s = asm.leading_dropped, asm.approach_speed_mm_s
        if len(xyz):
            self.last_xyz = xyz[-1].copy()

    def _first_layers(self, z_mm: np.ndarray, extruding: np.ndarray, layer: np.ndarray) -> None:
        """The lowest extruding nozzle height of the first two layers, so far (a chunk past them adds nothing)."""
        if not extruding.any() or int(layer[extruding].min()) > 1:
            return
        for k, name in ((0, "first_layer_z_mm"), (1, "second_layer_z_mm")):
            rows = extruding & (layer == k)
            if rows.any():
                setattr(self, name, min(getattr(self, name), float(z_mm[rows].min())))
