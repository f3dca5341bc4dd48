"""Plan the same G-code on every built-in cell and write what was decided: ``python plan_signature.py OUT.npz``.

Run by ``tests/test_any_cpu.py`` once per numpy kernel mask (``support.kernels``): each cell's joints, IK
statuses, rotations about the nozzle and TCP quaternions go into OUT.npz, and the test compares the runs. The
G-code holds what makes choices close: the nozzle straight down at every heading (quaternions with w = 0, the
wrist flip), circles round the plate's centre, a square near the plate's edges, and for the multi-axis cell a
ridge laid with the nozzle along its normal.
"""
from __future__ import annotations

import sys

import numpy as np

from fabric.planning import PlanOptions, plan_gcode
from fabric.robot.cell import Cell, builtin_cell_names

LAYER_MM = 0.3


def planar_gcode(layers: int = 4) -> str:
    """Circles of 5-40 mm radius about (100, 100), then a 180 mm square, layer after layer (plate frame, mm)."""
    out = ["G21", "G90", "M83", "M104 S205", "M109 S205"]
    e = 0.05
    for layer in range(layers):
        z = LAYER_MM * (layer + 1)
        out += [";LAYER_CHANGE", f";Z:{z:.3f}", f"G0 X140.000 Y100.000 Z{z + 1.0:.3f} F6000", f"G0 Z{z:.3f}"]
        for r in (40.0, 25.0, 12.0, 5.0):
            a = np.linspace(0.0, 2.0 * np.pi, 73)
            out += [f"G1 X{100.0 + r * np.cos(t):.3f} Y{100.0 + r * np.sin(t):.3f} E{e:.4f} F1800" for t in a]
        for x, y in ((10.0, 10.0), (190.0, 10.0), (190.0, 190.0), (10.0, 190.0), (10.0, 10.0)):
            out.append(f"G1 X{x:.3f} Y{y:.3f} E{e * 20:.4f} F1800")
    return "\n".join(out) + "\n"


def ridge_gcode(layers: int = 4, curve: float = 0.0577) -> str:
    """Layers over a ridge along y about (100, 100), the nozzle along the surface's normal (multi-axis)."""
    out = ["; multiaxis: nozzle axis in I J K", "G21", "G90", "M83", "M104 S205", "M109 S205"]
    steps = np.arange(-5.0, 5.0 + 1e-9, 0.5)
    for layer in range(layers):
        z0 = LAYER_MM * (layer + 1)
        out += [";LAYER_CHANGE", f";Z:{z0:.3f}"]
        for j, dx in enumerate(steps):
            z = z0 + curve * dx * dx
            axis = np.array([-2.0 * curve * dx, 0.0, 1.0])
            axis /= np.linalg.norm(axis)
            ijk = f"I{axis[0]:.4f} J{axis[1]:.4f} K{axis[2]:.4f}"
            ys = steps if j % 2 == 0 else steps[::-1]
            if j == 0:
                out += [f"G0 X{100 + dx:.3f} Y{100 + ys[0]:.3f} Z{z + 2.0:.3f} {ijk} F6000", f"G0 Z{z:.3f} {ijk}"]
            out += [f"G1 X{100 + dx:.3f} Y{100 + y:.3f} Z{z:.3f} {ijk} E0.01 F1200" for y in ys[1:]]
    return "\n".join(out) + "\n"


def signatures() -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for name in builtin_cell_names():
        cell = Cell.builtin(name)
        texts = {"planar": planar_gcode()}
        if "multiaxis" in name:
            texts["ridge"] = ridge_gcode()
        for what, text in texts.items():
            result = plan_gcode(text.encode(), cell, PlanOptions())
            prog = result.program
            key = f"{name}/{what}"
            out[f"{key}/q_rad"] = np.asarray(prog.q_rad)
            out[f"{key}/quat_wxyz"] = np.asarray(prog.quat_wxyz)
            out[f"{key}/status"] = np.asarray(result.report.status)
            out[f"{key}/rot_deg"] = np.asarray(result.report.rot_deg)
    return out


if __name__ == "__main__":
    np.savez(sys.argv[1], **signatures())
