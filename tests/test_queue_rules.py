"""The print queue's rules (pure): the head loads when prepared, the station free and the plate clear; the
others say what they wait for."""
from __future__ import annotations

from fabric import schemas as s
from fabric.printjobs.queue import next_to_load


def _job(job_id: str, prepared: bool = True, state: str = "queued") -> s.JobRecord:
    return s.JobRecord(job_id=job_id, filename=f"{job_id}.stl", state=state, prepared=prepared)


def test_the_prepared_head_loads_when_the_station_is_free_and_the_plate_clear():
    a, b = _job("a"), _job("b")
    d = next_to_load([a, b], None, plate_clear=True)
    assert d.load is a and d.waits == [(b, "queue")]


def test_the_head_waits_for_the_plate_then_for_the_station_and_an_unprepared_head_for_nothing():
    a, b = _job("a"), _job("b")
    assert next_to_load([a, b], None, plate_clear=False).waits == [(b, "queue"), (a, "plate")]
    busy = _job("x", state="printing")
    d = next_to_load([a], busy, plate_clear=True)
    assert d.load is None and d.waits == [(a, "station")]
    d = next_to_load([_job("c", prepared=False), b], None, plate_clear=True)
    assert d.load is None and d.waits == [(b, "queue")]
    assert next_to_load([], None, True).load is None
