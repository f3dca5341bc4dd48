"""Pictures: a PNG of a toolpath (a program's or a G-code file's; extruding moves coloured by layer, travel
faint) and a PNG of recorded telemetry (temperatures, speed, flow, extrusion against simulated time)."""
from __future__ import annotations

import io
from collections.abc import Mapping
from typing import Any

import numpy as np

from fabric.motion.program import MOVEL, PRINT, Program

__all__ = ["toolpath_png", "gcode_png", "segments_png", "telemetry_png", "flow_profile"]


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return matplotlib, plt


def toolpath_png(program: Program, title: str = "toolpath", max_segments: int = 200_000,
                 layer: int | None = None) -> bytes:
    """Render a program's print section in the plate frame (3D view plus top view) as PNG bytes."""
    rows = np.flatnonzero((program.section == PRINT) & (program.op == MOVEL))
    rows = rows[rows > 0]
    seg = np.stack([program.xyz_mm[rows - 1], program.xyz_mm[rows]], axis=1)
    axis = None
    if program.meta.get("multiaxis", False):      # the nozzle axis: minus the TCP's z
        from fabric.sim.deposition import nozzle_axes
        axis = nozzle_axes(program.quat_wxyz[rows])
    return segments_png(seg, program.flow_mm3_mm[rows] > 0, program.layer[rows], title, max_segments, layer, axis)


def gcode_png(toolpath: Any, title: str = "toolpath", max_segments: int = 200_000, layer: int | None = None) -> bytes:
    """Render an interpreted G-code file (``fabric.gcode.Toolpath``, machine coordinates) as PNG bytes."""
    ends = toolpath.xyz_mm
    starts = np.concatenate([toolpath.start_xyz_mm[None, :], ends[:-1]]) if len(ends) else ends
    seg = np.stack([starts, ends], axis=1)
    return segments_png(seg, toolpath.e_mm > 0, toolpath.layer, title, max_segments, layer,
                        getattr(toolpath, "axis", None))


def segments_png(seg: np.ndarray, extruding: np.ndarray, layer: np.ndarray, title: str = "toolpath",
                 max_segments: int = 200_000, only_layer: int | None = None, axis: np.ndarray | None = None) -> bytes:
    """3D view and top view of segments ``seg`` (n, 2, 3) mm. With ``only_layer`` (0-based) the 3D view
    shows the part up to that layer and the top view that layer alone. With ``axis`` (n, 3: the nozzle axis at
    each segment's end, curved layers) a third view shows a slice of the part from the front: the layers as
    the curves they are, and the nozzle's tilt along the one shown (or the last)."""
    matplotlib, plt = _pyplot()
    from matplotlib.collections import LineCollection
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    ext = np.asarray(extruding, dtype=bool)
    layer = np.asarray(layer)
    axis = None if axis is None else np.asarray(axis, dtype=float)
    if only_layer is not None:
        keep = layer <= only_layer
        seg, ext, layer = seg[keep], ext[keep], layer[keep]
        axis = None if axis is None else axis[keep]
    if len(seg) > max_segments:   # keep the picture cheap on million-move programs
        keep = np.linspace(0, len(seg) - 1, max_segments).astype(int)
        seg, ext, layer = seg[keep], ext[keep], layer[keep]
        axis = None if axis is None else axis[keep]
    colors = matplotlib.colormaps["viridis"]((layer - layer.min()) / max(1, np.ptp(layer)) if len(layer) else [])

    panels = 2 if axis is None else 3
    fig = plt.figure(figsize=(5.5 * panels, 5), dpi=110)
    ax = fig.add_subplot(1, panels, 1, projection="3d")
    ax.add_collection3d(Line3DCollection(seg[ext], colors=colors[ext], linewidths=0.6), autolim=False)
    ax.add_collection3d(Line3DCollection(seg[~ext], colors=(0.8, 0.2, 0.2, 0.25), linewidths=0.3), autolim=False)
    if ext.any():
        pts = seg[ext].reshape(-1, 3)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        span = max(np.max(hi - lo), 1.0)
        mid = (lo + hi) / 2
        ax.auto_scale_xyz([mid[0] - span / 2, mid[0] + span / 2], [mid[1] - span / 2, mid[1] + span / 2],
                          [lo[2], lo[2] + span], had_data=False)
    ax.set_xlabel("x mm"), ax.set_ylabel("y mm"), ax.set_zlabel("z mm")
    n_layers = len(np.unique(layer[layer >= 0]))
    ax.set_title(f"{title}: {int(ext.sum())} extruding moves, {n_layers} layers")
    ax2 = fig.add_subplot(1, panels, 2)
    top = ext if only_layer is None else ext & (layer == only_layer)
    ax2.add_collection(LineCollection(seg[top][:, :, :2], colors=colors[top], linewidths=0.5))
    if only_layer is not None:
        travel = ~ext & (layer == only_layer)
        ax2.add_collection(LineCollection(seg[travel][:, :, :2], colors=(0.8, 0.2, 0.2, 0.3), linewidths=0.3))
    ax2.autoscale()
    ax2.set_aspect("equal")
    ax2.set_xlabel("x mm"), ax2.set_ylabel("y mm")
    ax2.set_title("top view" if only_layer is None else f"layer {only_layer + 1}")
    if axis is not None:
        _front_section(fig.add_subplot(1, 3, 3), seg, ext, layer, axis, colors, only_layer)
    return _png(fig, plt)


def _front_section(ax: Any, seg: np.ndarray, ext: np.ndarray, layer: np.ndarray, axis: np.ndarray,
                   colors: np.ndarray, only_layer: int | None) -> None:
    """The part cut by a slab through its middle (``y`` within 1.5 mm of the centre), seen from the front:
    every layer's beads in the slab as x-z curves, and the nozzle axis drawn along the layer shown (or the
    last) as short ticks: what curved layers and a tilted nozzle look like."""
    from matplotlib.collections import LineCollection

    if not ext.any():
        return
    ends = seg[:, 1]
    y_mid = float(np.median(ends[ext, 1]))
    slab = ext & (np.abs(seg[:, 0, 1] - y_mid) < 1.5) & (np.abs(ends[:, 1] - y_mid) < 1.5)
    ax.add_collection(LineCollection(list(seg[slab][:, :, [0, 2]]), colors=colors[slab], linewidths=0.8))
    shown = int(layer[ext].max()) if only_layer is None else only_layer
    tick = slab & (layer == shown)
    if tick.any():
        span = float(np.ptp(ends[ext, 0])) or 1.0
        at = np.flatnonzero(tick)
        x = ends[at, 0]                               # about 30 ticks across the part
        _, first = np.unique(np.floor((x - x.min()) / (span / 30.0)), return_index=True)
        at = at[first]
        tip = ends[at][:, [0, 2]]
        up = axis[at][:, [0, 2]] * (0.08 * span)
        ax.add_collection(LineCollection(list(np.stack([tip, tip + up], axis=1)), colors=(0.85, 0.1, 0.1, 0.8),
                                         linewidths=0.6))
    ax.autoscale()
    ax.set_aspect("equal")
    ax.set_xlabel("x mm"), ax.set_ylabel("z mm")
    ax.set_title(f"front section (y = {y_mid:.1f} mm): layers, nozzle axis on layer {shown + 1}")


def telemetry_png(columns: Mapping[str, np.ndarray], title: str = "telemetry") -> bytes:
    """Four panels against simulated time from a recording's columns (see ``fabric-cli record``):
    temperatures and set points, TCP speed and the speed override, extruder flow (its mean and its highest
    over time: :func:`flow_profile`) and the flow override, extruded volume."""
    _, plt = _pyplot()
    topic = np.asarray(columns["topic"]).astype(str)
    t = np.asarray(columns["t_sim_s"], dtype=float)

    def col(name: str, which: str) -> tuple[np.ndarray, np.ndarray]:
        rows = (topic == which)
        if name not in columns:
            return np.zeros(0), np.zeros(0)
        v = np.asarray(columns[name], dtype=float)[rows]
        order = np.argsort(t[rows], kind="stable")
        return t[rows][order], v[order]

    fig, axes = plt.subplots(4, 1, figsize=(10, 10), dpi=100, sharex=True)
    ax = axes[0]
    for name, colour in (("nozzle_c", "tab:red"), ("bed_c", "tab:blue")):
        ts, v = col(name, "temps")
        ax.plot(ts, v, color=colour, label=name.replace("_c", " C"))
        ts, v = col(name.replace("_c", "_target_c"), "temps")
        ax.plot(ts, v, color=colour, linestyle=":", label=name.replace("_c", " set point"))
    ax.set_ylabel("deg C"), ax.legend(loc="upper right", fontsize=8)
    ax = axes[1]
    ts, x = col("x_mm", "pose")
    _, y = col("y_mm", "pose")
    _, z = col("z_mm", "pose")
    if len(ts) > 1:
        dt = np.diff(ts)
        ok = dt > 0
        speed = np.linalg.norm(np.diff(np.stack([x, y, z], axis=1), axis=0), axis=1)[ok] / dt[ok]
        ax.plot(ts[1:][ok], speed, color="tab:green", linewidth=0.7, label="TCP speed mm/s")
    ax.set_ylabel("mm/s"), ax.legend(loc="upper left", fontsize=8)
    twin = ax.twinx()
    ts, v = col("speed_r", "state")
    twin.step(ts, v, where="post", color="tab:gray", label="speed override")
    twin.set_ylabel("override x"), twin.legend(loc="upper right", fontsize=8)
    ax = axes[2]
    ts, v = col("extruded_mm3", "extrusion")       # the flow switches on and off every bead: drawn as its mean
    mid, mean, peak = flow_profile(ts, v, *col("flow_mm3_s", "extrusion"))
    ax.plot(mid, mean, color="tab:purple", label="mean flow mm3/s")
    ax.plot(mid, peak, color="tab:purple", linewidth=0.6, alpha=0.5, label="highest flow mm3/s")
    ax.set_ylim(bottom=0.0)
    ax.set_ylabel("mm3/s"), ax.legend(loc="upper left", fontsize=8)
    twin = ax.twinx()
    ts, v = col("flow_r", "extrusion")
    twin.step(ts, v, where="post", color="tab:gray", label="flow override")
    twin.set_ylabel("override x"), twin.legend(loc="upper right", fontsize=8)
    ax = axes[3]
    ts, v = col("extruded_mm3", "extrusion")
    ax.plot(ts, v, color="tab:orange", label="extruded mm3")      # (the extruder's on/off: the mean flow above)
    ax.set_ylabel("mm3"), ax.set_xlabel("simulated time s"), ax.legend(loc="upper left", fontsize=8)
    axes[0].set_title(title)
    return _png(fig, plt)


def flow_profile(t_s: np.ndarray, extruded_mm3: np.ndarray, flow_t_s: np.ndarray, flow_mm3_s: np.ndarray,
                 bins: int = 120) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The extruder's flow over a print as ``bins`` time bins: the mean (the volume deposited in each bin over
    its length) and the highest sampled flow in each. Sampled flow switches between zero and the bead's flow
    at every travel, which drawn as it is fills the panel as one block."""
    if len(t_s) < 2 or t_s[-1] <= t_s[0]:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    edges = np.linspace(t_s[0], t_s[-1], bins + 1)
    volume = np.interp(edges, t_s, extruded_mm3)
    mean = np.diff(volume) / np.diff(edges)
    peak = np.zeros(bins)
    if len(flow_t_s):
        which = np.clip(np.searchsorted(edges, flow_t_s, side="right") - 1, 0, bins - 1)
        np.maximum.at(peak, which, np.nan_to_num(flow_mm3_s))
    return (edges[:-1] + edges[1:]) / 2, mean, np.maximum(peak, mean)


def _png(fig: Any, plt: Any) -> bytes:
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()
