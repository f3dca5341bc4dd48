"""The collision service over real in-process Zenoh peers: programs by id, and the station's live moves
checked against the beads the twin has actually laid (station/beads, kept between checks)."""
from __future__ import annotations

import numpy as np
import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.motion.testprog import square_program
from fabric.programs import program_artifact
from fabric.robot.cell import Cell
from fabric.services.collision import CollisionService
from fabric.services.planner import PlannerService
from fabric.services.station import StationService
from fabric.wire.errors import BadRequest, CollisionError, ValidationError

pytestmark = pytest.mark.timeout(240)


@pytest.fixture(scope="module")
def cell():
    return Cell.builtin("irb140")


@pytest.fixture
def fabric(session, settings, cell):
    """Station, collision and planner services in this process, a client, and a 12-layer tower program."""
    planner = PlannerService(session, settings.cell, cell)
    collision = CollisionService(session, settings.cell, cell)
    station = StationService(session, settings.cell, cell, pose_hz=50.0)
    program = square_program(cell, size_mm=20, layers=12, layer_height_mm=0.5, speed_mm_s=60, nozzle_c=200.0)
    pid = planner.store_artifact(program_artifact(program))
    for svc in (planner, collision, station):
        svc.start()
    with Client.connect(settings) as client:
        client.wait_alive(("station", "collision", "planner"), deadline_s=20)
        yield client, station, collision, pid, program
    for svc in (station, collision, planner):
        svc.close()


def wait_event(sub, kinds: tuple[str, ...], timeout: float = 120.0) -> s.Event:
    while True:
        ev = sub.get(timeout=timeout)
        if ev.kind in kinds:
            return ev


def test_a_program_by_id_is_certified_against_its_own_beads(fabric):
    client, _, _, pid, _ = fabric
    rep = client.check(s.CollisionRequest(program_id=pid))
    assert rep.collision_free and rep.first_hit is None
    assert rep.beads == 12 * 4 and rep.segments > 40 and rep.min_distance_mm > 0.3
    assert rep.clearance_body and rep.exemption.startswith("tool_tip")
    old = client.check(s.CollisionRequest(program_id=pid, step_deg=5.0))      # a version 1 request still works
    assert old.collision_free


def test_bad_single_moves_get_typed_errors(fabric, cell):
    client = fabric[0]
    with pytest.raises(BadRequest):
        client.check(s.CollisionRequest(q_from_deg=[0.0] * 6))
    with pytest.raises(BadRequest):
        client.check(s.CollisionRequest(q_from_deg=[0.0] * 5, q_to_deg=[0.0] * 6))
    with pytest.raises(ValidationError):
        client.check(s.CollisionRequest(q_from_deg=[0.0] * 6, q_to_deg=[0.0] * 6, beads="everything"))


def test_live_moves_are_checked_against_the_beads_the_twin_laid(fabric, cell):
    client, _, collision, pid, program = fabric
    home = np.degrees(cell.home_q_rad).tolist()
    above = np.degrees(program.q_rad[3]).tolist()            # above the tower's first corner (the approach)
    before = client.check(s.CollisionRequest(q_from_deg=home, q_to_deg=above, beads="station"))
    assert before.collision_free and before.beads == 0
    client.load(pid)
    events = client.subscribe("station", "events")
    try:
        client.start(rtf=0)
        assert wait_event(events, ("finished", "fault")).kind == "finished"
    finally:
        events.close()
    page = client.call("station", "beads", s.BeadsQuery(first=0, limit=5))
    assert page.total == 12 * 4 and len(page.row) == 5 and page.first == 0 and page.part_id
    assert np.all(page.gcode_line == program.gcode_line[page.row])
    # the station's own check of a restart at layer 1: the move goes down inside the printed tower
    with pytest.raises(CollisionError) as err:
        client.start(rtf=0, from_layer=0)
    assert "the move to layer 1 would collide" in err.value.message and "hits the part" in err.value.message
    assert err.value.details["kind"] == "restart" and err.value.details["bead"] >= 0
    assert len(collision.station_beads.solids) == 12 * 4           # kept: the next check asks for nothing new
    part = collision.station_beads.part_id
    rep = client.check(s.CollisionRequest(q_from_deg=home, q_to_deg=home[:5] + [home[5] + 1.0], beads="station"))
    assert rep.collision_free and rep.beads == 12 * 4 and collision.station_beads.part_id == part
    # the top layer: at home the robot is far above it; the same move with the part ignored would pass
    free = client.check(s.CollisionRequest(q_from_deg=home, q_to_deg=above))
    assert free.collision_free
    hit = client.check(s.CollisionRequest(q_from_deg=home, q_to_deg=above, beads="station")).first_hit
    assert hit is not None and hit.body_b == "part" and hit.bead_layer >= 1


def deg(q: np.ndarray) -> list[float]:
    return np.degrees(q).tolist()


def print_tower(client) -> None:
    events = client.subscribe("station", "events")
    try:
        client.start(rtf=0)
        assert wait_event(events, ("finished", "fault")).kind == "finished"
    finally:
        events.close()


def test_a_restart_whose_descent_goes_through_the_part_is_refused_and_changes_nothing(fabric):
    """Layer 10 of the 12-layer tower: the joint move ends 5 mm above the layer's first point, 4 mm over the
    top (free), but the straight way down from there goes through layers 11 and 12."""
    client, station, _, pid, _ = fabric
    client.load(pid)
    print_tower(client)
    path, vel_r = station.commands.read(lambda: (station.twin.moves.restart_path(station.twin.restart_point(9)),
                                                 station.twin.config.home_vel_r))
    joint_only = client.check(s.CollisionRequest(q_from_deg=deg(path.q_from_rad), q_to_deg=deg(path.q_above_rad),
                                                 beads="station", tip_layer=-2, kind="restart", vel_r=vel_r))
    assert joint_only.collision_free                  # the move the station checked before: free
    before, last_seq, where = client.state(), client.events(0).last_seq, client.position().q_deg
    with pytest.raises(CollisionError) as err:
        client.start(rtf=0, from_layer=9)
    hit = err.value.details
    assert hit["kind"] == "descent" and hit["body_b"] == "part" and hit["bead_layer"] in (10, 11)
    assert hit["body_a"].startswith("tool_") and 0.0 < hit["move_r"] < 1.0
    assert err.value.message.startswith("the move to layer 10 would collide: the descent move: tool_")
    # refused: nothing changed, and the station goes on serving
    after = client.state()
    assert (after.state, after.program_id, after.job_id) == (before.state, before.program_id, before.job_id)
    assert client.events(0).last_seq == last_seq and client.position().q_deg == where
    # the top layer again: nothing is left of it to print; the layer under it: no move hits on its way up
    # the part (the tip runs over its old beads' top), but every bead of it would go into the part
    with pytest.raises(ValidationError, match="layer 12 is printed to its end and no layer follows it"):
        client.start(rtf=0, from_layer=11)
    station_row = station.commands.read(lambda: station.twin.restart_point(10).row)
    report = client.check(s.CollisionRequest(program_id=pid, from_row=station_row, beads="station",
                                             q_start_deg=deg(path.q_down_rad)))
    hit = report.first_hit
    assert hit is not None and hit.kind == "deposit" and hit.body_a == "bead" and hit.layer == 11
    assert hit.bead_layer == 11 and "its bead would go into the part on the plate (a bead of layer 12" in hit.message
    after = client.state()
    assert (after.state, after.deposited_mm3) == (before.state, before.deposited_mm3)
    assert client.events(0).last_seq == last_seq


def stop_tower_in_layer(client, layer: int) -> None:
    """Print the tower and stop it once it has begun ``layer`` (0-based): the part's top is that layer."""
    events = client.subscribe("station", "events")
    try:
        client.start(rtf=20.0)
        while True:
            ev = events.get(timeout=60.0)
            if ev.kind == "layer" and ev.layer >= layer:
                break
            assert ev.kind not in ("finished", "fault"), ev
        client.stop()
        assert wait_event(events, ("stopped", "fault")).kind == "stopped"
    finally:
        events.close()


def test_a_recovery_at_a_layer_under_the_part_is_refused_by_its_descent(fabric):
    """Stopped near the top, restarted where the part ends and interrupted there, recovered two layers under
    its top: the descent is checked like a restart's; back to the interrupted spot, the print finishes."""
    client, station, _, pid, _ = fabric
    client.load(pid)
    stop_tower_in_layer(client, 10)
    top = station.commands.read(station.plate.top_layer)
    assert top >= 9
    events = client.subscribe("station", "events")
    try:
        client.start(rtf=0.5, from_layer=top)                # where the part ends, slowly
        assert wait_event(events, ("at_layer", "fault")).kind == "at_layer"
        station.commands.change(lambda: station.twin.interrupt("killed by the test"))   # it dies where it is
        assert client.state().state == "interrupted"
        with pytest.raises(CollisionError) as err:
            client.recover(rtf=0, from_layer=top - 2)
        assert err.value.details["kind"] == "descent" and err.value.details["bead_layer"] in (top - 1, top)
        assert f"the move back to layer {top - 1} would collide: the descent move" in err.value.message
        assert client.state().state == "interrupted"
        client.recover(rtf=0)                                # back to the interrupted spot, and on
        assert wait_event(events, ("finished", "fault")).kind == "finished"
    finally:
        events.close()
