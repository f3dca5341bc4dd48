"""fabric-cli plot draws the extruder's flow as its mean over time, not as a block of on/off steps (issue 24)."""
from __future__ import annotations

import numpy as np
import pytest

from fabric.viz import flow_profile, telemetry_png


def beads(seconds: float = 600.0, period_s: float = 2.0, flow_mm3_s: float = 4.0):
    """An extruder on for half of every ``period_s`` (a bead, then a travel), sampled as the station publishes."""
    t = np.arange(0.0, seconds, 0.05)
    on = (t % period_s) < period_s / 2
    flow = np.where(on, flow_mm3_s, 0.0)
    extruded = np.concatenate([[0.0], np.cumsum(flow[:-1] * np.diff(t))])
    return t, extruded, flow


def test_the_mean_flow_is_a_line_at_the_average_and_the_peak_at_the_bead_flow():
    t, extruded, flow = beads()
    mid, mean, peak = flow_profile(t, extruded, t, flow, bins=60)
    assert len(mid) == len(mean) == len(peak) == 60
    assert mean == pytest.approx(np.full(60, 2.0), abs=0.25)           # half the time at 4 mm3/s
    assert peak == pytest.approx(np.full(60, 4.0))
    assert np.sum(np.diff(mid) * mean[1:]) == pytest.approx(extruded[-1], rel=0.02)   # the volume is kept


def test_the_plot_still_renders_from_a_recording():
    t, extruded, flow = beads(60.0)
    cols = {"topic": np.array(["extrusion"] * len(t)), "t_sim_s": t, "extruded_mm3": extruded,
            "flow_mm3_s": flow, "on": (flow > 0).astype(float), "flow_r": np.ones_like(t)}
    png = telemetry_png(cols)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert flow_profile(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))[0].size == 0
