"""Jog and manual extrude while idle (issue 24), through real services: the station certifies a jog against
the table, the plate and the part before it moves; it refuses to push filament through a cold nozzle, and
while a print is on; what it refuses changes nothing."""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest

from fabric import schemas as s
from fabric.cli.main import main
from fabric.client import Client
from fabric.robot.cell import Cell
from fabric.services.collision import CollisionService
from fabric.services.station import StationService
from fabric.wire.errors import CollisionError, StateError, ValidationError

pytestmark = pytest.mark.timeout(180)


def wait_event(client: Client, since: int, kind: str, timeout_s: float = 60.0) -> s.Event:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        for ev in client.events(since).events:
            if ev.kind == kind:
                return ev
        time.sleep(0.02)
    raise AssertionError(f"no {kind} event within {timeout_s:g} s")


def next_seq(client: Client) -> int:
    return client.events(limit=1).last_seq + 1


def test_jog_and_extrude_by_hand(session, settings, tmp_path, capsys):
    cell = Cell.builtin("irb140")
    services = [CollisionService(session, settings.cell, cell),
                StationService(session, settings.cell, cell, data_dir=tmp_path / "station")]
    for svc in services:
        svc.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station", "collision"), deadline_s=20)
            client.set_rtf(100.0)           # the clock runs at 100x while idle (rtf 0 is max speed only when printing)
            before = np.asarray(client.position().xyz_mm)

            # a jog: a straight move in the plate frame, the nozzle's orientation kept; an event at its end.
            # Home is beside the plate: over the plate's middle
            d = np.array([125.0, 125.0, 0.0]) - before * [1, 1, 0] + [0.0, 0.0, -40.0]
            since = next_seq(client)
            ack = client.jog(*d, speed_mm_s=50.0)
            assert "jogging" in ack.message
            ev = wait_event(client, since, "jogged")
            assert np.allclose(ev.data["xyz_mm"], before + d, atol=1e-6)
            after = client.position()
            assert np.allclose(after.xyz_mm, before + d, atol=1e-6)
            assert client.state().reason == "jogged"

            # down near the plate in steps of at most 200 mm, then through it: refused by the collision check,
            # and the robot does not move
            while after.xyz_mm[2] > 60.0:
                since = next_seq(client)
                client.jog(dz_mm=-min(200.0, after.xyz_mm[2] - 50.0), speed_mm_s=200.0)
                wait_event(client, since, "jogged")
                after = client.position()
            seq = next_seq(client)
            with pytest.raises(CollisionError) as hit:
                client.jog(dz_mm=-float(after.xyz_mm[2]) - 5.0)
            assert hit.value.details["kind"] == "jog" and hit.value.details["body_b"] in ("plate", "table")
            assert np.allclose(client.position().xyz_mm, after.xyz_mm) and next_seq(client) == seq
            with pytest.raises(ValidationError, match="longer than"):
                client.jog(dx_mm=500.0)
            with pytest.raises(ValidationError, match="non-zero"):
                client.jog()
            with pytest.raises(ValidationError):                    # the schema's bound: at most 200 mm/s
                client.jog(dz_mm=1.0, speed_mm_s=1000.0)
            with pytest.raises(ValidationError, match="non-zero"):
                client.extrude(0.0)
            assert np.allclose(client.position().xyz_mm, after.xyz_mm) and next_seq(client) == seq

            # filament by hand: refused cold (nothing changes), pushed once the nozzle is hot
            with pytest.raises(StateError, match="below the minimum extrusion temperature"):
                client.extrude(10.0)
            client.overrides(nozzle_c=210.0)
            temps = client.subscribe("station", "temps")
            try:
                while temps.get(timeout=30).nozzle_c < 205.0:
                    pass
            finally:
                temps.close()
            since = next_seq(client)
            args = replace(settings, mode="client").to_args()
            assert main(["extrude", "12", "--speed", "4", *args]) == 0
            assert "extruding 12 mm" in capsys.readouterr().out
            assert wait_event(client, since, "extruded").data == {"filament_mm": 12.0}
            assert client.state().reason == "extruded 12 mm"
            assert client.state().deposited_mm3 == 0.0                   # a purge is not part of the part
            since = next_seq(client)
            assert main(["jog", "--z", "10", *args]) == 0
            wait_event(client, since, "jogged")
    finally:
        for svc in reversed(services):
            svc.close()


@pytest.mark.parametrize("name", ["irb140", "ur5", "panda"])
def test_a_long_jog_keeps_to_its_straight_line(name: str) -> None:
    """Interpolating the joints of a 200 mm jog's two ends swings the nozzle 15-29 mm off the line; the jog is
    made in pieces whose interpolation keeps within JOG_LINE_TOL_MM, sampled along the twin's own motion."""
    from fabric.sim.manual import JOG_LINE_TOL_MM, jog_plan
    from fabric.sim.twin import Twin
    cell = Cell.builtin(name)
    twin = Twin(cell)
    start = twin.pose()
    d = np.array([200.0, 0.0, 0.0]) if name != "panda" else np.array([0.0, 150.0, -100.0])
    plan = jog_plan(twin.moves, d)
    wobj = plan.wobj
    a = np.asarray(start.xyz_mm, dtype=float)
    whole = cell.robot.tcp_xyz_mm(0.5 * (np.asarray(start.q_rad) + plan.q_rad[-1]))[0]
    assert np.linalg.norm(whole - (wobj[:3, :3] @ (a + 0.5 * d) + wobj[:3, 3])) > 5.0     # one piece would stray
    assert len(plan.q_rad) > 3
    np.testing.assert_allclose(plan.xyz_mm[-1], a + d, atol=1e-9)
    twin.jog(d, 100.0)
    far = 0.0
    while twin.moving:
        twin.advance(0.05)
        tcp = cell.robot.tcp_xyz_mm(twin.pose().q_rad)[0]
        p = np.linalg.solve(wobj[:3, :3], tcp - wobj[:3, 3]) - a          # plate frame, from the start
        s = np.clip(p @ d / (d @ d), 0.0, 1.0)
        far = max(far, float(np.linalg.norm(p - s * d)))
    assert far <= JOG_LINE_TOL_MM + 1e-6, far
    np.testing.assert_allclose(twin.pose().xyz_mm, a + d, atol=1e-6)


def test_a_jog_whose_line_needs_a_new_arm_configuration_is_refused_and_changes_nothing() -> None:
    """On the IRB 140, 200 mm towards the base then 200 mm more: the second line crosses where the wrist must
    turn over (a joint jump on the line): refused with a typed error naming the point, nothing queued."""
    from fabric.sim.twin import Twin
    from fabric.wire.errors import UnreachableError
    twin = Twin(Cell.builtin("irb140"))
    twin.jog([-200.0, 0.0, 0.0], 200.0)
    while twin.moving:
        twin.advance(0.5)
    before = twin.pose()
    with pytest.raises(UnreachableError, match=r"straight line at .* is not a motion of the arm") as err:
        twin.jog([-200.0, 0.0, 0.0], 200.0)
    assert err.value.details["reason"] == "joint jump"
    assert not twin.moving
    np.testing.assert_array_equal(twin.pose().q_rad, before.q_rad)
