"""Nothing moves unless certified against the part as it stands (issue: a restart printed the whole part again
into itself). For a finished part and for a stopped one, a restart at every layer under the part's top is
refused with nothing moved; going on where the part ends finishes with the plate holding the planned volume
(within 1 %); calibrating with a part on the plate is refused until it is off."""
from __future__ import annotations

import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.motion.testprog import square_program
from fabric.programs import program_artifact
from fabric.robot.cell import Cell
from fabric.services.collision import CollisionService
from fabric.services.planner import PlannerService
from fabric.services.station import StationService
from fabric.wire.errors import CollisionError, StateError, ValidationError

pytestmark = pytest.mark.timeout(240)
LAYERS = 6


@pytest.fixture
def cell_services(session, settings):
    cell = Cell.builtin("irb140")
    planner = PlannerService(session, settings.cell, cell)
    collision = CollisionService(session, settings.cell, cell)
    station = StationService(session, settings.cell, cell)
    program = square_program(cell, size_mm=20, layers=LAYERS, layer_height_mm=0.5, speed_mm_s=40, nozzle_c=200.0)
    pid = planner.store_artifact(program_artifact(program))
    for svc in (planner, collision, station):
        svc.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station", "collision", "planner"), deadline_s=20)
            yield client, station, pid
    finally:
        for svc in (station, collision, planner):
            svc.close()


def _until(client: Client, kinds: tuple[str, ...], start: dict | None = None, stop_in_layer: int = -1) -> s.Event:
    events = client.subscribe("station", "events")
    try:
        if start is not None:
            client.start(**start)
        while True:
            ev = events.get(timeout=60.0)
            if stop_in_layer >= 0 and ev.kind == "layer" and ev.layer >= stop_in_layer:
                client.set_rtf(0.5)
                _first_bead_of_layer(client, ev.layer)
                client.stop()
                stop_in_layer = -1
            if ev.kind in kinds:
                return ev
    finally:
        events.close()


def _first_bead_of_layer(client: Client, layer: int) -> None:
    """Wait until the part has a bead of ``layer`` (the state's layer and volume say so)."""
    base = client.state().deposited_mm3
    extrusion = client.subscribe("station", "extrusion")
    try:
        while extrusion.get(timeout=30.0).extruded_mm3 <= base:
            pass
    finally:
        extrusion.close()


def _refused_everywhere_under(client: Client, station: StationService, top: int) -> None:
    """``start --layer k`` for every layer under the part's top: refused, nothing moved or changed."""
    before, seq, where = client.state(), client.events(0).last_seq, client.position().q_deg
    for layer in range(top):
        with pytest.raises((CollisionError, ValidationError)) as err:
            client.start(rtf=0, from_layer=layer)
        assert "would collide" in err.value.message or "nothing is left" in err.value.message, err.value.message
        after = client.state()
        assert (after.state, after.deposited_mm3, after.plate_mm3) == (before.state, before.deposited_mm3,
                                                                       before.plate_mm3), layer
        assert client.events(0).last_seq == seq and client.position().q_deg == where, layer


def test_a_finished_part_refuses_every_restart(cell_services) -> None:
    client, station, pid = cell_services
    client.load(pid)
    assert _until(client, ("finished", "fault"), {"rtf": 0}).kind == "finished"
    st = client.state()
    assert st.plate_mm3 == pytest.approx(st.planned_mm3, rel=0.01)
    _refused_everywhere_under(client, station, LAYERS)          # the top layer too: nothing is left of it
    with pytest.raises(StateError, match="cannot calibrate while the plate holds the part"):
        client.calibrate()
    assert client.state().plate_mm3 == pytest.approx(st.plate_mm3)
    assert "taken off" in client.clear_plate().message
    assert client.calibrate().points > 0                        # the plate is clear: the probe may go


def test_a_stopped_part_goes_on_only_where_it_ends_and_ends_with_the_planned_volume(cell_services) -> None:
    client, station, pid = cell_services
    client.load(pid)
    assert _until(client, ("stopped", "fault"), {"rtf": 10.0}, stop_in_layer=3).kind == "stopped"
    top = station.commands.read(station.plate.top_layer)
    assert top == 3
    _refused_everywhere_under(client, station, top)
    with pytest.raises(StateError, match="in the air"):
        client.start(rtf=0, from_layer=top + 2)
    events = client.subscribe("station", "events")
    try:
        ack = client.start(rtf=0, from_layer=top)
        assert f"from layer {top + 1}, where the part ends (heating" in ack.message
        while (ev := events.get(timeout=60.0)).kind not in ("finished", "fault"):
            pass
        assert ev.kind == "finished"
    finally:
        events.close()
    st = client.state()
    assert st.plate_mm3 == pytest.approx(st.planned_mm3, rel=0.01)
