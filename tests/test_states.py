"""States are enums with questions (fabric.schemas.states), and on the wire the strings they always were."""
from __future__ import annotations

import msgpack
import pytest

from fabric import schemas as s
from fabric.schemas import states
from fabric.wire import codec
from fabric.wire.errors import ValidationError


def _record(**kw) -> s.JobRecord:
    return s.JobRecord(job_id="a1", filename="f.gcode", source="gcode", profile="", backend="builtin",
                       model_id="0" * 64, **kw)


def test_the_questions_answer_as_the_states_mean() -> None:
    st = states.Station
    assert [x for x in st if x.in_print] == [st.PRINTING, st.PAUSED]
    assert [x for x in st if x.print_on] == [st.PRINTING, st.PAUSED, st.INTERRUPTED]
    assert [x for x in st if x.free] == [st.IDLE, st.READY, st.STOPPED, st.FAULT]
    pj = states.PrintJob
    assert [x for x in pj if x.ended] == [pj.FINISHED, pj.STOPPED, pj.FAILED]
    assert [x for x in pj if x.waiting] == [pj.QUEUED, pj.SLICING, pj.PLANNING, pj.CHECKING]
    assert [x for x in pj if x.on_station] == [pj.LOADED, pj.PRINTING, pj.PAUSED, pj.INTERRUPTED]
    assert [x for x in states.Job if x.ended] == [states.Job.DONE, states.Job.FAILED]
    assert s.FINAL_JOB_STATES == ("finished", "stopped", "failed")      # the tuples come from the enums


def test_a_state_is_its_string_on_the_wire_and_a_member_in_the_code() -> None:
    rec = _record(state="printing")                     # built with a plain string: a member
    assert rec.state is states.PrintJob.PRINTING and rec.state.printing and not rec.state.ended
    rec.state = "finished"                              # set later, too
    assert rec.state is states.PrintJob.FINISHED and rec.state.ended
    assert f"{rec.state}" == str(rec.state) == "finished" and rec.state == "finished"
    raw = msgpack.unpackb(codec.encode(rec))
    assert raw["state"] == "finished" and type(raw["state"]) is str
    back = codec.decode(codec.encode(rec), s.JobRecord)
    assert back.state is states.PrintJob.FINISHED and back == rec
    q = codec.decode(codec.encode(s.JobsQuery(states=["queued", "paused"])), s.JobsQuery)
    assert q.states == [states.PrintJob.QUEUED, states.PrintJob.PAUSED] and q.states[1].printing


def test_a_string_that_is_no_state_is_refused_naming_the_field() -> None:
    with pytest.raises(ValidationError, match="'bogus' is not one of") as err:
        _record(state="bogus")
    assert err.value.details == {"field": "state", "schema": "supervisor.JobRecord"}
    rec = _record()
    with pytest.raises(ValidationError):
        rec.state = "done"                              # a plan job's state, not a print job's
    assert rec.state is states.PrintJob.QUEUED          # refused: unchanged
    wire = msgpack.unpackb(codec.encode(_record()))
    wire["state"] = "printing!"
    with pytest.raises(ValidationError) as err:
        codec.decode(msgpack.packb(wire), s.JobRecord)
    assert err.value.details["field"] == "state"
