"""What a telemetry sample repaints in the console: the panels it changes, not the whole screen, and nothing
when it shows nothing new. An idle console took 62 % of a core re-rendering every widget at every sample
(the station samples its pose at 50 Hz whether the robot moves or not)."""
from __future__ import annotations

import asyncio
from dataclasses import replace

from textual._compositor import Compositor

from fabric import schemas as s
from fabric.tui.app import FabricConsole
from fabric.tui.widgets.joints_panel import JointsPanel
from fabric.tui.widgets.toolpath_view import ToolpathView

POSE = s.Pose(seq=1, t_sim_s=1.0, q_deg=[0.0, 10.0, 20.0, 0.0, 90.0, 0.0], xyz_mm=[120.0, 90.0, 50.0],
              quat_wxyz=[0.0, 1.0, 0.0, 0.0], base_xyz_mm=[480.0, 10.0, 200.0])


def test_a_sample_repaints_only_what_it_changes(monkeypatch) -> None:
    renders = {JointsPanel: 0, ToolpathView: 0, Compositor: 0}      # Compositor: updates of the whole screen
    full_update = Compositor.render_full_update

    def counted_full(self, *args, **kwargs):
        renders[Compositor] += 1
        return full_update(self, *args, **kwargs)
    monkeypatch.setattr(Compositor, "render_full_update", counted_full)
    for cls in (JointsPanel, ToolpathView):
        original = cls.render

        def counted(self, _original=original, _cls=cls):
            renders[_cls] += 1
            return _original(self)
        monkeypatch.setattr(cls, "render", counted)

    async def scenario() -> None:
        app = FabricConsole(None)
        async with app.run_test(size=(160, 48)) as pilot:
            app.cell = "cell1"
            app.pose = POSE
            await pilot.pause()
            assert app.screen.query_one(JointsPanel).pose is POSE
            before = dict(renders)
            # the robot at rest: samples with new numbers and clocks only
            for k in range(2, 12):
                app.pose = replace(POSE, seq=k, t_sim_s=float(k))
                await pilot.pause()
            assert renders == before, "a pose that shows nothing new repainted the panels or the screen"
            assert app.screen.query_one(JointsPanel).pose is POSE
            # the robot moves: its panel and the layer view follow
            moved = replace(POSE, seq=12, q_deg=[1.0, 10.0, 20.0, 0.0, 90.0, 0.0], xyz_mm=[121.0, 90.0, 50.0])
            app.pose = moved
            await pilot.pause()
            assert renders[JointsPanel] > before[JointsPanel] and renders[ToolpathView] > before[ToolpathView]
            assert renders[Compositor] == before[Compositor], "a pose repainted the whole screen"
            assert app.screen.query_one(JointsPanel).pose is moved
            assert app.screen.query_one(ToolpathView).nozzle_xyz_mm == [121.0, 90.0, 50.0]
            # a cell switch clears the pose: the panel says so even if the same pose comes again after
            app.pose = None
            await pilot.pause()
            assert app.screen.query_one(JointsPanel).pose is None
            app.pose = moved
            await pilot.pause()
            assert app.screen.query_one(JointsPanel).pose is moved

    asyncio.run(scenario())
