"""Round trip over every schema, hypothesis-driven, and decoders fed garbage."""
from __future__ import annotations

import types
import typing
from typing import Any, Union

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fabric.schemas import REGISTRY
from fabric.wire import codec
from fabric.wire.errors import DecodeError, ValidationError

SCHEMAS = sorted(REGISTRY.items())
FAST = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _strategy(tp: Any, spec=None) -> st.SearchStrategy:
    origin = typing.get_origin(tp)
    if origin in (Union, types.UnionType):
        inner = next(a for a in typing.get_args(tp) if a is not type(None))
        return st.one_of(st.none(), _strategy(inner, spec))
    if tp is Any:
        return st.one_of(st.integers(-5, 5), st.text(max_size=5), st.booleans())
    if spec is not None and spec.choices is not None and origin is not list:
        return st.sampled_from(spec.choices)
    if tp is float:
        lo = spec.ge if spec and spec.ge is not None else -1e9
        hi = spec.le if spec and spec.le is not None else 1e9
        return st.floats(lo, hi, allow_nan=False)
    if tp is int:
        lo = int(spec.ge) if spec and spec.ge is not None else -(2 ** 40)
        hi = int(spec.le) if spec and spec.le is not None else 2 ** 40
        return st.integers(lo, hi)
    if tp is bool:
        return st.booleans()
    if tp is str:
        if spec is not None and spec.pattern is not None:
            return st.from_regex(spec.pattern, fullmatch=True).filter(lambda v: len(v) <= (spec.max_len or 64))
        shortest = spec.min_len if spec is not None and spec.min_len else 0
        return st.text(min_size=shortest, max_size=spec.max_len if spec and spec.max_len else 20)
    if tp is bytes:
        return st.binary(max_size=64)
    if tp is np.ndarray:
        shape = spec.shape if spec and spec.shape else (3,)
        shape = tuple(s if s is not None else 2 for s in shape)
        return st.builds(lambda v: np.full(shape, v, dtype=spec.dtype if spec and spec.dtype else "<f8"),
                         st.floats(-1e6, 1e6))
    if origin is list:
        (item,) = typing.get_args(tp)
        n = spec.shape[0] if spec and spec.shape and spec.shape[0] is not None else None
        sub = type(spec)(spec.name, item, True, ge=spec.ge, le=spec.le, choices=spec.choices) if spec else None
        return st.lists(_strategy(item, sub), min_size=n or 0, max_size=n or 3)
    if origin is dict:
        _, vt = typing.get_args(tp)
        return st.dictionaries(st.text(max_size=5), _strategy(vt), max_size=3)
    if hasattr(tp, "SPECS"):
        return _message(tp)
    raise AssertionError(f"no strategy for {tp}")


def _message(cls) -> st.SearchStrategy:
    fields = {name: _strategy(spec.tp, spec) for name, spec in cls.SPECS.items()}
    return st.fixed_dictionaries(fields).map(lambda kw: cls(**kw))


def _equal(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b)
    if hasattr(a, "SPECS"):
        return type(a) is type(b) and all(_equal(getattr(a, k), getattr(b, k)) for k in a.SPECS)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b, strict=True))
    return a == b


@pytest.mark.parametrize("name,cls", SCHEMAS, ids=[n for n, _ in SCHEMAS])
def test_round_trip(name, cls):
    @FAST
    @given(_message(cls))
    def check(msg):
        back = codec.decode(codec.encode(msg), cls)
        assert _equal(msg, back)
    check()


@pytest.mark.parametrize("name,cls", SCHEMAS, ids=[n for n, _ in SCHEMAS])
def test_garbage_is_a_typed_error(name, cls):
    values = st.one_of(st.integers(-2 ** 63, 2 ** 63 - 1), st.floats(), st.text(max_size=8), st.none(),
                       st.binary(max_size=8), st.lists(st.integers(0, 9), max_size=3))
    keys = st.one_of(st.sampled_from(sorted(cls.SPECS) or ["x"]), st.text(max_size=6))
    tagged = st.dictionaries(keys, values, max_size=6).map(lambda d: {**d, "_t": name, "_v": 1})
    @FAST
    @given(st.one_of(st.binary(max_size=200), st.builds(msgpack.packb, tagged),
                     st.builds(msgpack.packb, st.dictionaries(st.text(max_size=6), values, max_size=5))))
    def check(data):
        try:
            codec.decode(data, cls)
        except (DecodeError, ValidationError):
            pass
    check()


def test_wrong_field_names_the_field():
    from fabric.schemas import Overrides, SliceRequest
    with pytest.raises(ValidationError) as e:
        codec.decode(codec.pack({"_t": "station.Overrides", "_v": 1, "speed_r": "fast"}), Overrides)
    assert e.value.details["field"] == "speed_r"
    with pytest.raises(ValidationError) as e:
        codec.decode(codec.pack({"_t": "slicer.SliceRequest", "_v": 1, "model": b"x"}), SliceRequest)
    assert e.value.details["field"] == "filename"
    with pytest.raises(ValidationError) as e:
        codec.decode(codec.pack({"_t": "station.Overrides", "_v": 1, "bogus": 1}), Overrides)
    assert e.value.details["field"] == "bogus"


def test_version_and_type_are_checked():
    from fabric.schemas import Overrides, Pose
    with pytest.raises(DecodeError, match="version"):
        codec.decode(codec.pack({"_t": "station.Overrides", "_v": 99}), Overrides)
    with pytest.raises(DecodeError, match=r"expected station\.Pose"):
        codec.decode(codec.encode(Overrides()), Pose)


def test_arrays_travel_packed_not_as_lists():
    from fabric.schemas import ProgramMsg
    arr = np.arange(3000, dtype="<f8").reshape(1000, 3)
    data = codec.encode(ProgramMsg(columns={"xyz_mm": arr}))
    assert len(data) < arr.nbytes + 300           # binary, not 3000 msgpack floats of 9 bytes
    raw = msgpack.unpackb(data)
    packed = raw["columns"]["xyz_mm"]
    assert packed["dtype"] == "<f8" and packed["shape"] == [1000, 3]
    assert np.array_equal(np.frombuffer(packed["data"], "<f8").reshape(1000, 3), arr)


def test_lying_array_header_is_rejected():
    bad = codec.pack({"_t": "planner.ProgramMsg", "_v": 1,
                      "columns": {"a": {"nd": True, "dtype": "<f8", "shape": [10, 3], "data": b"\0" * 8}}})
    from fabric.schemas import ProgramMsg
    with pytest.raises(DecodeError, match="does not match"):
        codec.decode(bad, ProgramMsg)
    evil = codec.pack({"_t": "planner.ProgramMsg", "_v": 1,
                       "columns": {"a": {"nd": True, "dtype": "|O", "shape": [1], "data": b"\0" * 8}}})
    with pytest.raises(DecodeError, match="dtype"):
        codec.decode(evil, ProgramMsg)


def test_decode_any_reads_the_type_tag():
    from fabric.schemas import Pose, StationState
    msg = codec.decode_any(codec.encode(StationState(state="paused", reason="operator")))
    assert isinstance(msg, StationState) and msg.state == "paused"
    with pytest.raises(DecodeError, match="type tag"):
        codec.decode_any(codec.pack({"_t": "no.Such", "_v": 1}))
    with pytest.raises(ValidationError):
        codec.decode_any(codec.pack({"_t": Pose.TYPE, "_v": 1, "seq": 1}))


@pytest.mark.parametrize("cls_name,field,nested", [
    ("PlanSummary", "first_unreachable", "UnreachableTarget"),
    ("PlanSummary", "first_slowed", "SlowedMove"),
    ("CollisionReport", "first_hit", "CollisionHit"),
    ("FabricStatus", "job", "JobRecord"),
    ("JobStatus", "error", "ErrorReply"),
])
def test_fields_callers_read_are_schemas(cls_name, field, nested):
    from fabric import schemas
    hints = typing.get_type_hints(getattr(schemas, cls_name))
    assert hints[field] == getattr(schemas, nested) | None


def test_job_list_holds_job_records():
    from fabric.schemas import JobList, JobRecord
    assert typing.get_type_hints(JobList)["jobs"] == list[JobRecord]


def test_nested_schema_is_validated_with_its_dotted_path():
    from fabric.schemas import CollisionReport, PlanSummary
    base = {"_t": "planner.PlanSummary", "_v": 2, "program_id": "p", "targets": 1, "moves": 1, "layers": 1,
            "feasible_r": 0.5, "runnable": False, "estimate_s": -1.0, "extruded_mm3": 0.0, "path_mm": 0.0}
    ok = codec.decode(codec.pack({**base, "first_unreachable": {"gcode_line": 6, "reason": "out of reach"}}),
                      PlanSummary)
    assert ok.first_unreachable.gcode_line == 6 and ok.first_unreachable.row == -1
    with pytest.raises(ValidationError) as e:
        codec.decode(codec.pack({**base, "first_unreachable": {"gcode_line": 6, "reason": 1}}), PlanSummary)
    assert e.value.details["field"] == "first_unreachable.reason"
    with pytest.raises(ValidationError) as e:
        codec.decode(codec.pack({**base, "first_unreachable": {"gcode_line": 6, "reason": "far away"}}),
                     PlanSummary)
    assert e.value.details["field"] == "first_unreachable.reason"
    with pytest.raises(ValidationError) as e:
        codec.decode(codec.pack({"_t": "collision.Report", "_v": 2, "collision_free": False, "checked_configs": 3,
                                 "min_distance_mm": 0.0, "first_hit": {"body_a": "link_2"}}), CollisionReport)
    assert e.value.details["field"] == "first_hit.body_b"


def test_unreachable_reason_is_one_word_of_the_vocabulary():
    from fabric.robot.kinematics import IK_OK, IK_REASONS, ik_reason
    from fabric.wire.errors import UNREACHABLE_REASONS, UnreachableError, error_from_code
    err = UnreachableError("far", reason="out of reach", gcode_line=6)
    assert err.details == {"reason": "out of reach", "gcode_line": 6}
    with pytest.raises(TypeError, match="reason"):
        UnreachableError("far", reason=1)                 # an IK status code is not a reason: use ik_reason
    from fabric.planning.envelope import ENVELOPE_REASONS
    ik = {ik_reason(code) for code in IK_REASONS if code != IK_OK}
    assert ik | set(ENVELOPE_REASONS.values()) == set(UNREACHABLE_REASONS) and not ik & set(ENVELOPE_REASONS.values())
    assert ik_reason(np.uint8(1)) == "out of reach"
    with pytest.raises(ValueError):
        ik_reason(IK_OK)
    back = error_from_code("unreachable", "far", err.to_wire()["details"])
    assert isinstance(back, UnreachableError) and back.details["reason"] == "out of reach"


@pytest.mark.parametrize("name,cls", SCHEMAS, ids=[n for n, _ in SCHEMAS])
def test_encode_pieces_gives_the_bytes_of_encode(name, cls):
    """Large messages are written from pieces (arrays referenced, not copied): the same bytes."""
    @FAST
    @given(_message(cls))
    def check(msg):
        assert b"".join(codec.encode_pieces(msg)) == codec.encode(msg)
    check()


def test_encode_pieces_references_large_data_and_splices_pieces():
    from fabric.schemas import Artifact
    big = np.arange(300_000, dtype="<f8")
    data = b"x" * 200_000
    art = Artifact(artifact_id="a" * 64, name="n", media_type="m", data=data)
    pieces = codec.encode_pieces(art)
    assert any(p is data for p in pieces) and b"".join(pieces) == codec.encode(art)
    assert b"".join(codec.encode_pieces(Artifact(artifact_id="a" * 64, name="n", media_type="m",
                                                 data=codec.Spliced([data[:5], memoryview(data)[5:]])))) \
        == codec.encode(art)
    from fabric.schemas import ProgramMsg
    msg = ProgramMsg(columns={"q_rad": big.reshape(-1, 6)})
    pieces = codec.encode_pieces(msg)
    assert any(isinstance(p, memoryview) and np.shares_memory(np.frombuffer(p, dtype=np.uint8), big) for p in pieces)
    assert b"".join(pieces) == codec.encode(msg)
