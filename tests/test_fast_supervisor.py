"""The supervisor's handlers driven through the client over the memory fabric (fast tier), with stand-ins for
the station and the planner: status from liveliness and health, job queries, typed refusals, and a print job
whose preparation fails with the planner's typed error. The whole cell as processes is test_e2e.py's."""
from __future__ import annotations

import queue

import msgpack
import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.server.service import Service
from fabric.services.supervisor import SupervisorService
from fabric.wire import codec
from fabric.wire.errors import NotFound, UnreachableError, ValidationError

CELL = "cell1"
WAIT_S = 10.0       # a deadline for what happens at once; never reached when the feature works
GCODE = b"G28\nG1 Z0.2 F1200\nG1 X10 Y10 E1 F1200\n"


class StandInStation(Service):
    """The station as the supervisor asks it: its state, and an empty event log."""

    name = "station"
    partial = True

    def __init__(self, session, cell: str) -> None:
        super().__init__(session, cell)
        self.handle("state", lambda _: s.StationState(state="idle"))
        self.handle("events", lambda req: s.EventList(events=[], next_seq=req.since_seq))


class RefusingPlanner(Service):
    """A planner that finds the first target out of reach."""

    name = "planner"
    partial = True

    def __init__(self, session, cell: str) -> None:
        super().__init__(session, cell)
        self.plans: queue.Queue[s.PlanRequest] = queue.Queue()
        self.handle("plan", self.on_plan)
        self.serve_pins()

    def on_plan(self, req: s.PlanRequest) -> s.JobAccepted:
        self.plans.put(req)
        raise UnreachableError("G-code line 3 is out of reach", reason="out of reach", gcode_line=3)


@pytest.fixture
def supervisor(memory_fabric):
    svc = SupervisorService(memory_fabric.session(), CELL)
    svc.start()
    yield svc
    svc.close()


@pytest.fixture
def client(memory_fabric, supervisor):
    c = Client(memory_fabric.session(), CELL)
    c.wait_alive(("supervisor",), deadline_s=WAIT_S)
    return c


@pytest.fixture
def stand_ins(memory_fabric):
    services = [StandInStation(memory_fabric.session(), CELL), RefusingPlanner(memory_fabric.session(), CELL)]
    for svc in services:
        svc.start()
    yield services
    for svc in services:
        svc.close()


def test_status_lists_every_service_alive_or_not_with_its_health(client, stand_ins):
    client.wait_alive(("supervisor", "station", "planner"), deadline_s=WAIT_S)
    st = client.status()
    by_name = {i.name: i for i in st.services}
    assert st.cell == CELL and list(by_name) == ["station", "slicer", "planner", "collision", "supervisor"]
    assert {n for n, i in by_name.items() if i.alive} == {"station", "planner", "supervisor"}
    assert by_name["planner"].health == "ok" and by_name["slicer"].health == ""
    assert st.job is None and st.station_cell is None     # the stand-in station serves no cell model


def test_an_unknown_job_is_not_found_and_the_queue_starts_empty(client):
    with pytest.raises(NotFound, match="no job deadbeef"):
        client.job("deadbeef")
    page = client.jobs()
    assert (page.jobs, page.total) == ([], 0)


def test_garbage_and_invalid_fields_are_typed_errors_and_it_keeps_serving(client, supervisor):
    key = client.keys.cmd("supervisor", "status")
    for garbage in (b"\xc1\xff garbage", msgpack.packb({"_t": "nope", "_v": 1})):
        replies = list(client.session.get(key, payload=garbage, timeout=WAIT_S))
        assert codec.decode(replies[0].err.payload.to_bytes(), s.ErrorReply).code == "decode"
    bad = codec.pack({"_t": "supervisor.JobSubmit", "_v": 1, "model": b"x", "filename": "a.stl", "rtf": -3.0})
    with pytest.raises(ValidationError) as e:
        client.call_raw("supervisor", "submit", bad, s.JobAccepted, WAIT_S)
    assert e.value.details["field"] == "rtf"
    assert client.status().cell == CELL and supervisor.degraded is None


def test_a_gcode_job_with_slicing_overrides_is_refused(client):
    with pytest.raises(ValidationError, match="not sliced") as e:
        client.submit(s.JobSubmit(model=GCODE, filename="part.gcode", overrides={"layer_height_mm": "0.3"}))
    assert e.value.details["field"] == "overrides"
    assert client.jobs().total == 0


def test_a_job_the_planner_refuses_fails_with_its_typed_error(client, stand_ins):
    planner = stand_ins[1]
    client.wait_alive(("station", "planner"), deadline_s=WAIT_S)
    published = client.subscribe("supervisor", "jobs")
    try:
        job_id = client.submit(s.JobSubmit(model=GCODE, filename="part.gcode")).job_id
        with pytest.raises(UnreachableError, match="out of reach") as e:
            client.wait_print_job(job_id, lambda rec: False, timeout=WAIT_S)
        assert e.value.details["gcode_line"] == 3
        assert planner.plans.get(timeout=WAIT_S).gcode == GCODE        # the G-code went to the planner as is
        rec = client.job(job_id)
        assert (rec.state, rec.source, rec.error.code) == ("failed", "gcode", "unreachable")
        states = []
        while "failed" not in states:
            msg = published.get(timeout=WAIT_S)
            if msg.job_id == job_id:
                states.append(str(msg.state))
        assert states[0] == "queued" and "planning" in states        # every change was published
    finally:
        published.close()
    assert client.job_remove(job_id).ok
    with pytest.raises(NotFound):
        client.job(job_id)
