"""The operator console driven with Textual's Pilot against the cell's processes."""
from __future__ import annotations

import asyncio
from dataclasses import replace

import pytest

from fabric.client import Client
from fabric.keys import SERVICES
from fabric.tui.app import FabricConsole
from fabric.tui.widgets.services import ServicesPanel
from fabric.tui.widgets.telemetry import PosePanel

pytestmark = pytest.mark.timeout(120)


async def until(pilot, predicate, timeout_s: float = 60.0) -> None:
    """Let the app run until ``predicate()`` holds (bounded)."""
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout_s
    while not predicate():
        assert loop.time() < end, "condition not reached in time"
        await pilot.pause(0.05)


def log_text(app) -> str:
    return "\n".join(strip.text for strip in app.query_one("#log").lines)


def test_console_shows_services_pose_and_runs_commands(running_cell):
    async def scenario() -> None:
        with Client.connect(replace(running_cell.settings, mode="client")) as client:
            app = FabricConsole(client)
            async with app.run_test(size=(120, 40)) as pilot:
                await until(pilot, lambda: all(app.query_one(ServicesPanel).alive.get(n) for n in SERVICES))
                await until(pilot, lambda: app.query_one(PosePanel).pose is not None)
                assert "TCP (plate)" in app.query_one(PosePanel).render()
                await pilot.press("y")                     # station ready?
                await until(pilot, lambda: "READY" in log_text(app))
                assert "services alive" in log_text(app)
                await pilot.click("#cmd-pause")            # nothing is printing: a clear, typed refusal
                await until(pilot, lambda: "pause failed [state]" in log_text(app))
    asyncio.run(scenario())


def test_console_follows_services_coming_and_going(hub, session, settings):
    """Liveliness changes reach the services panel through the client's subscription (no polling)."""
    from fabric.keys import Keys

    async def scenario() -> None:
        with Client.connect(replace(settings, mode="client")) as client:
            app = FabricConsole(client)
            async with app.run_test(size=(120, 40)) as pilot:
                panel = app.query_one(ServicesPanel)
                await until(pilot, lambda: panel.alive.get("planner") is False)     # the first query: nobody
                token = session.liveliness().declare_token(Keys(settings.cell).alive("planner"))
                await until(pilot, lambda: panel.alive.get("planner") is True)
                token.undeclare()
                await until(pilot, lambda: panel.alive.get("planner") is False)
    asyncio.run(scenario())


def test_console_without_a_hub_says_so_in_one_line():
    import subprocess
    import sys
    r = subprocess.run([sys.executable, "-m", "fabric.tui", "--connect", "tcp/127.0.0.1:1"], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [r.stderr.strip()] and "cannot reach the fabric hub" in r.stderr
    assert "Traceback" not in r.stderr
