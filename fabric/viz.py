"""Pictures of programs: a PNG of the toolpath (extruding moves coloured by layer, travel faint)."""
from __future__ import annotations

import io

import numpy as np

from fabric.motion.program import MOVEL, PRINT, Program

__all__ = ["toolpath_png"]


def toolpath_png(program: Program, title: str = "toolpath", max_segments: int = 200_000) -> bytes:
    """Render the print section in the plate frame (3D view plus top view) as PNG bytes."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Line3DCollection
    from matplotlib.collections import LineCollection

    rows = np.flatnonzero((program.section == PRINT) & (program.op == MOVEL))
    rows = rows[rows > 0]
    seg = np.stack([program.xyz_mm[rows - 1], program.xyz_mm[rows]], axis=1)
    ext = program.flow_mm3_mm[rows] > 0
    if len(seg) > max_segments:   # keep the picture cheap on million-move programs
        keep = np.linspace(0, len(seg) - 1, max_segments).astype(int)
        seg, ext, rows = seg[keep], ext[keep], rows[keep]
    layer = program.layer[rows]
    colors = matplotlib.colormaps["viridis"]((layer - layer.min()) / max(1, np.ptp(layer)) if len(layer) else [])

    fig = plt.figure(figsize=(11, 5), dpi=110)
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    ax.add_collection3d(Line3DCollection(seg[ext], colors=colors[ext], linewidths=0.6), autolim=False)
    ax.add_collection3d(Line3DCollection(seg[~ext], colors=(0.8, 0.2, 0.2, 0.25), linewidths=0.3), autolim=False)
    if len(seg):
        lo, hi = seg.reshape(-1, 3).min(axis=0), seg.reshape(-1, 3).max(axis=0)
        span = max(np.max(hi - lo), 1.0)
        mid = (lo + hi) / 2
        ax.auto_scale_xyz([mid[0] - span / 2, mid[0] + span / 2], [mid[1] - span / 2, mid[1] + span / 2],
                          [lo[2], lo[2] + span], had_data=False)
    ax.set_xlabel("x mm"), ax.set_ylabel("y mm"), ax.set_zlabel("z mm")
    ax.set_title(f"{title}: {int(ext.sum())} extruding moves, {len(np.unique(layer))} layers")
    ax2 = fig.add_subplot(1, 2, 2)
    ax2.add_collection(LineCollection(seg[ext][:, :, :2], colors=colors[ext], linewidths=0.5))
    ax2.autoscale()
    ax2.set_aspect("equal")
    ax2.set_xlabel("x mm (plate frame)"), ax2.set_ylabel("y mm")
    ax2.set_title("top view")
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()
