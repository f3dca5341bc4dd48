"""The slicer's handlers driven through the client over the memory fabric (fast tier): a slice as a job with
its progress stream, its result and G-code artifact, pins, and typed refusals; the built-in back-end only
(the external slicers are processes: test_slicing_external.py)."""
from __future__ import annotations

import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.services.slicer import SlicerService
from fabric.slicing.samples import box, to_stl_bytes
from fabric.wire.errors import BadRequest, MeshError, NotFound

CELL = "cell1"
WAIT_S = 30.0       # a deadline for a small slice; never reached when the feature works


@pytest.fixture
def slicer(memory_fabric):
    svc = SlicerService(memory_fabric.session(), CELL, (200.0, 200.0), 100.0)
    svc.start()
    yield svc
    svc.close()


@pytest.fixture
def client(memory_fabric, slicer):
    return Client(memory_fabric.session(), CELL)


def test_a_slice_is_a_job_whose_result_and_gcode_are_kept(client):
    accepted = client.slice(s.SliceRequest(model=to_stl_bytes(box((10.0, 10.0, 2.0))), filename="box.stl"))
    seen: list[s.JobStatus] = []
    done = client.wait_job("slicer", accepted.job_id, timeout=WAIT_S, on_progress=seen.append)
    assert (accepted.kind, done.state) == ("slice", "done") and seen[-1].state == "done"
    result = client.slice_result(done.result_id)
    assert result.backend == "builtin" and result.layers > 0 and result.extruded_mm3 > 0
    gcode = client.artifact("slicer", result.gcode_id)
    assert gcode.name == "box.gcode" and gcode.media_type == "text/x-gcode" and b"G1" in gcode.data
    assert client.pin("slicer", result.gcode_id, "job1").ok and client.unpin("slicer", "job1").ok


def test_a_broken_model_fails_its_job_with_the_typed_error(client):
    accepted = client.slice(s.SliceRequest(model=b"not an stl at all", filename="broken.stl"))
    with pytest.raises(MeshError, match="not an STL"):
        client.wait_job("slicer", accepted.job_id, timeout=WAIT_S)


def test_requests_that_cannot_succeed_are_refused_at_once(client):
    model = to_stl_bytes(box((10.0, 10.0, 2.0)))
    with pytest.raises(NotFound, match="unknown profile"):
        client.slice(s.SliceRequest(model=model, filename="box.stl", profile="nope"))
    with pytest.raises(BadRequest, match="curved layers need the builtin"):
        client.slice(s.SliceRequest(model=model, filename="box.stl", backend="prusaslicer", layers="curved"))
    with pytest.raises(NotFound, match="no slicing result"):
        client.slice_result("0" * 64)
    with pytest.raises(NotFound, match="no artifact"):
        client.pin("slicer", "0" * 64, "job1")


def test_the_backends_list_names_the_builtin_and_the_profiles(client):
    backends = client.backends()
    assert backends.backends["builtin"] and "taz-pla-medium" in backends.profiles
