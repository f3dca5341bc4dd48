"""The part on the plate is state: after a print it stays until the operator says it is off, a restart included;
a print from the beginning, a load and a restart at a layer of another part are refused meanwhile."""
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

pytestmark = pytest.mark.timeout(180)


def _print_to_end(client: Client, **start) -> s.Event:
    events = client.subscribe("station", "events")
    try:
        client.start(rtf=0, **start)
        while True:
            ev = events.get(timeout=60)
            if ev.kind in ("finished", "stopped", "fault"):
                return ev
    finally:
        events.close()


def test_the_part_on_the_plate_blocks_a_reprint_until_cleared_and_survives_a_restart(session, settings, tmp_path):
    cell = Cell.builtin("irb140")
    planner = PlannerService(session, settings.cell, cell)
    collision = CollisionService(session, settings.cell, cell)
    pid = planner.store_artifact(program_artifact(square_program(cell, size_mm=20, layers=3, nozzle_c=200.0)))
    other = planner.store_artifact(program_artifact(square_program(cell, size_mm=10, layers=2, nozzle_c=200.0)))
    station = StationService(session, settings.cell, cell, data_dir=tmp_path / "station")
    for svc in (planner, collision, station):
        svc.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station", "collision", "planner"), deadline_s=20)
            assert client.state().plate_clear
            client.load(pid)
            assert _print_to_end(client).kind == "finished"
            st = client.state()
            assert not st.plate_clear and st.plate_mm3 == pytest.approx(st.deposited_mm3) and st.plate_mm3 > 0
            with pytest.raises(StateError, match="plate holds the part") as err:
                client.start(rtf=0)                                  # not again onto the part
            assert err.value.details["plate"] == "occupied"
            with pytest.raises(StateError, match="plate holds"):
                client.load(other)
            after = client.state()
            assert after.state == st.state and after.deposited_mm3 == st.deposited_mm3   # nothing changed
            assert not client.ready().ready
            assert next(c for c in client.ready().checks if c.name == "plate clear").ok is False
            # the part is finished: nothing is left to print at its last layer, and a layer under it would be
            # printed into the part
            with pytest.raises(ValidationError, match="layer 3 is printed to its end and no layer follows it"):
                client.start(rtf=0, from_layer=2)
            with pytest.raises(CollisionError, match=r"the move to layer 2 would collide: .* hits the part") as err:
                client.start(rtf=0, from_layer=1)
            assert err.value.message.endswith("the part is printed to its last layer (3): take it off and say so "
                                              "(fabric-cli plate-clear) to print it again")
            with pytest.raises(StateError):
                client.start(rtf=0)
            mm3 = client.state().plate_mm3
            assert mm3 == pytest.approx(st.plate_mm3)                  # nothing was printed twice

        station.close()                                             # the station restarts: the part stays
        station = StationService(session, settings.cell, cell, data_dir=tmp_path / "station")
        station.start()
        with Client.connect(settings) as client:
            client.wait_alive(("station",), deadline_s=20)
            st = client.state()
            assert not st.plate_clear and st.plate_mm3 == pytest.approx(mm3)
            with pytest.raises(StateError, match="plate holds"):
                client.start(rtf=0)
            assert "taken off" in client.clear_plate().message
            st = client.state()
            assert st.plate_clear and st.plate_mm3 == 0
            kinds = [e.kind for e in client.events(0).events]
            assert kinds[-1] == "plate_cleared"
            with pytest.raises(StateError, match="plate is clear"):
                client.start(rtf=0, from_layer=1)                   # nothing to go on with
            client.load(other)
            events = client.subscribe("station", "events")
            client.start(rtf=1)
            with pytest.raises(StateError, match="still being printed"):
                client.clear_plate()
            client.stop()
            events.close()
    finally:
        for svc in (station, collision, planner):
            svc.close()
