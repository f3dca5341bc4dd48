"""The commanded-versus-measured TCP deviation of a run: streaming p50, p99, max and where the max was.

Every control step the driver streamed gives one figure: the distance from the TCP at the joints measured
then to the commanded path near that instant (:func:`path_deviation_mm`: the polyline of the commanded TCP
over the steps around it, both through the cell's kinematics, the nozzle's tip). It is the distance across
the path, not along it: a bead lands where the nozzle passes, so an arm a few milliseconds behind its
reference lays it on its line (its ends move by the speed times the lag: 0.3 mm at 20 mm/s for 15 ms); an
arm off to the side lays it off the line. A run keeps a histogram (1 um bins up to 50 mm, the rest in the
last) for its quantiles, and where its worst step was: the simulated time, the program's row and G-code line.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["DeviationStats", "BIN_MM", "TOP_MM", "path_deviation_mm"]

BIN_MM = 0.001
TOP_MM = 50.0


def path_deviation_mm(p_mm: np.ndarray, path_mm: np.ndarray) -> np.ndarray:
    """The distance (N,) from each point ``p_mm`` (N, 3) to the polyline ``path_mm`` (M, 3), M >= 1."""
    p = np.asarray(p_mm, dtype=float).reshape(-1, 3)
    a = np.asarray(path_mm, dtype=float).reshape(-1, 3)
    if len(a) == 1:
        return np.linalg.norm(p - a[0], axis=1)
    a0, d = a[:-1], np.diff(a, axis=0)                            # segments (M-1)
    dd = np.einsum("ij,ij->i", d, d)
    rel = p[:, None, :] - a0[None, :, :]                          # (N, M-1, 3)
    u = np.clip(np.einsum("nij,ij->ni", rel, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    closest = a0[None] + u[..., None] * d[None]
    return np.linalg.norm(p[:, None, :] - closest, axis=2).min(axis=1)


@dataclass
class Worst:
    mm: float = 0.0
    t_sim_s: float = 0.0
    row: int = -1
    gcode_line: int = -1


class DeviationStats:
    """The deviations of one run (reset when a run starts)."""

    def __init__(self) -> None:
        self.hist = np.zeros(int(TOP_MM / BIN_MM) + 1, dtype=np.int64)
        self.n = 0
        self.worst = Worst()
        self.last_mm = 0.0

    def add(self, dev_mm: np.ndarray, t_sim_s: float, row: int, gcode_line: int) -> None:
        """One tick's steps: their deviations (mm); where the program was at the tick."""
        dev = np.asarray(dev_mm, dtype=float).reshape(-1)
        if not len(dev):
            return
        np.add.at(self.hist, np.minimum((dev / BIN_MM).astype(np.int64), len(self.hist) - 1), 1)
        self.n += len(dev)
        self.last_mm = float(dev[-1])
        top = float(dev.max())
        if top > self.worst.mm:
            self.worst = Worst(top, float(t_sim_s), int(row), int(gcode_line))

    def quantile_mm(self, q: float) -> float:
        """The ``q`` quantile (0..1) of the run's deviations, to the bin (0 when none)."""
        if not self.n:
            return 0.0
        i = int(np.searchsorted(np.cumsum(self.hist), q * self.n, side="left"))
        return (i + 0.5) * BIN_MM

    def summary(self) -> dict[str, float | int]:
        """p50, p99, max (mm), the steps counted and where the max was: what a job's record keeps."""
        w = self.worst
        return {"p50_mm": round(self.quantile_mm(0.5), 4), "p99_mm": round(self.quantile_mm(0.99), 4),
                "max_mm": round(w.mm, 4), "steps": self.n, "max_t_sim_s": round(w.t_sim_s, 3),
                "max_row": w.row, "max_gcode_line": w.gcode_line}
