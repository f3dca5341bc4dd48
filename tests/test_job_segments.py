"""A job's record keeps every run of its print (issue 24): start, stop, restart at a layer, interruption,
recovery, each a segment, with the totals over them; and the overrides set while it printed."""
from __future__ import annotations

import pytest

from fabric import schemas as s
from fabric.printjobs.events import apply_event, job_id_of_event

JOB = "a1b2c3d4e5f6"


class Station:
    """Events as the station sends them for one job (its clock, its numbering, its deposit count)."""

    def __init__(self) -> None:
        self.seq, self.t_sim_s, self.layer, self.extruded_mm3, self.wall_s = 0, 100.0, -1, 0.0, 1000.0

    def event(self, kind: str, **data) -> s.Event:
        self.seq += 1
        return s.Event(seq=self.seq, t_sim_s=self.t_sim_s, kind=kind, layer=self.layer,
                       data={"job_id": JOB, **data})

    def run(self, rec: s.JobRecord, kind: str, after_s: float = 0.0, **data) -> s.JobRecord:
        self.t_sim_s += after_s
        self.wall_s += after_s / 10            # the print runs at 10x real time
        assert apply_event(rec, self.event(kind, **data), self.wall_s), kind
        return rec

    def layers(self, rec: s.JobRecord, upto: int, mm3_per_layer: float = 100.0, s_per_layer: float = 20.0) -> None:
        while self.layer < upto:
            self.layer += 1
            self.extruded_mm3 += mm3_per_layer
            self.run(rec, "layer", s_per_layer, z_mm=0.3 * (self.layer + 1))

    def totals(self) -> dict:
        return {"extruded_mm3": self.extruded_mm3, "filament_mm": self.extruded_mm3 / 2.4}


def record() -> s.JobRecord:
    plan = s.PlanSummary(program_id="p", targets=10, moves=10, layers=40, feasible_r=1.0, runnable=True,
                         estimate_s=800.0, extruded_mm3=4000.0, path_mm=1.0)
    return s.JobRecord(job_id=JOB, filename="part.gcode", state="loaded", plan=plan)


def test_a_stop_and_a_restart_at_the_layer_are_two_segments_with_totals() -> None:
    st, rec = Station(), record()
    st.run(rec, "started", from_row=0, from_layer=0)
    first_start = rec.started_s
    st.layers(rec, 24)
    st.run(rec, "stopped", 7.0, **st.totals())
    assert rec.state == "stopped" and rec.deposited_mm3 == 2500.0
    st.t_sim_s += 300.0                         # the operator looks, then restarts at layer 25
    st.wall_s += 300.0
    st.run(rec, "started", from_row=900, from_layer=24)
    assert rec.state == "printing" and rec.stage == "printing from layer 25" and rec.ended_s == 0.0
    st.extruded_mm3 -= 50.0                       # layer 25 is printed again (whole): more than planned in all
    st.layers(rec, 39)
    st.run(rec, "finished", 5.0, **st.totals())
    assert rec.state == "finished" and rec.started_s == first_start      # the start is the first run's
    one, two = rec.segments
    assert (one.began, one.from_layer, one.ended, one.last_layer) == ("start", 0, "stopped", 24)
    assert (two.began, two.from_layer, two.ended, two.last_layer) == ("restart", 24, "finished", 39)
    assert one.reason == "stopped by the operator" and two.reason == ""
    assert one.deposited_mm3 == 2500.0 and two.deposited_mm3 == pytest.approx(1450.0)
    assert rec.deposited_mm3 == pytest.approx(one.deposited_mm3 + two.deposited_mm3)
    assert one.sim_s == pytest.approx(25 * 20.0 + 7.0) and two.sim_s == pytest.approx(15 * 20.0 + 5.0)
    assert rec.sim_elapsed_s == pytest.approx(one.sim_s + two.sim_s)    # the 300 s between the runs are not in it
    assert rec.wall_elapsed_s == pytest.approx((one.ended_s - one.started_s) + (two.ended_s - two.started_s))


def test_an_interruption_and_its_recovery_are_kept() -> None:
    st, rec = Station(), record()
    st.run(rec, "started", from_row=0, from_layer=0)
    st.layers(rec, 9)
    st.run(rec, "paused", 3.0, reason="paused by operator")
    st.run(rec, "resumed", 60.0)
    st.run(rec, "interrupted", 4.0, reason="the station stopped (killed)", **st.totals())
    assert rec.state == "interrupted" and rec.stage.startswith("interrupted")
    st.run(rec, "recovered", 30.0)
    st.layers(rec, 19)
    st.run(rec, "finished", 2.0, **st.totals())
    one, two = rec.segments
    assert (one.ended, one.reason, one.pauses) == ("interrupted", "the station stopped (killed)", 1)
    assert (two.began, two.from_layer, two.ended) == ("recover", 9, "finished")
    assert one.deposited_mm3 == 1000.0 and two.deposited_mm3 == 1000.0 and rec.deposited_mm3 == 2000.0


def test_overrides_set_while_printing_are_in_the_record() -> None:
    st, rec = Station(), record()
    st.run(rec, "started", from_row=0, from_layer=0)
    st.layers(rec, 2)
    override = st.event("override", speed_r=1.5, flow_r=1.1)
    assert job_id_of_event(override) == JOB
    assert apply_event(rec, override, st.wall_s)
    (o,) = rec.live_overrides
    assert (o.speed_r, o.flow_r, o.nozzle_c, o.layer) == (1.5, 1.1, None, 2)
    st.layers(rec, 4)
    st.run(rec, "finished", 1.0, **st.totals())
    assert not apply_event(rec, st.event("override", speed_r=2.0), st.wall_s)    # the job is over: not its own
    assert len(rec.live_overrides) == 1


def test_a_record_printing_before_segments_existed_gets_one() -> None:
    st, rec = Station(), record()
    rec.state, rec.started_s, rec.sim_elapsed_s, rec.layer = "printing", 900.0, 50.0, 3
    st.layer = 3
    st.extruded_mm3 = 400.0
    st.run(rec, "finished", 10.0, elapsed_s=60.0, **st.totals())      # the station says how long it ran
    (seg,) = rec.segments
    assert seg.began == "start" and seg.ended == "finished" and seg.started_s == 900.0
    assert rec.sim_elapsed_s == pytest.approx(60.0)
