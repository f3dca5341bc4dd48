"""Bounded inputs: sizes checked before reading, large files sent in pieces and assembled on disk."""
from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
import trimesh

from fabric import schemas as s
from fabric.cli.inputs import LIMIT_ENV, LargeInput, gcode_source, read_input, read_whole
from fabric.client import Client, input_size
from fabric.robot.cell import Cell
from fabric.schemas.upload import INLINE_MAX_BYTES, UPLOAD_CHUNK_MAX_BYTES
from fabric.server.uploads import UploadStore
from fabric.services.planner import PlannerService
from fabric.services.slicer import SlicerService
from fabric.wire.errors import BadRequest, ConfigError, NotFound, ValidationError

pytestmark = pytest.mark.timeout(120)

GCODE = ("; filament_diameter = 2.85\nG21\nG90\nM83\nM104 S200\nM109 S200\nG1 Z0.3 F600\n"
         + "".join(f"G1 X{60 + (k % 40) * 2} Y{60 + k // 40} E0.1 F1800\n" for k in range(2000))).encode()


def _chunks(data: bytes, uid: str, size: int) -> list[s.UploadChunk]:
    pieces = [data[i:i + size] for i in range(0, len(data), size)] or [b""]
    digest = hashlib.sha256(data).hexdigest()
    out, offset = [], 0
    for k, piece in enumerate(pieces):
        last = k == len(pieces) - 1
        out.append(s.UploadChunk(upload_id=uid, offset=offset, total_bytes=len(data), data=piece,
                                 sha256=digest if last else ""))
        offset += len(piece)
    return out


# -- the store ----------------------------------------------------------------------------------
def test_pieces_in_order_make_the_file(tmp_path: Path) -> None:
    store = UploadStore(tmp_path, max_bytes=1 << 20)
    statuses = [store.put(c) for c in _chunks(GCODE, "upload-1", 1000)]
    assert [st.done for st in statuses] == [False] * (len(statuses) - 1) + [True]
    assert statuses[-1].received_bytes == len(GCODE) and store.path("upload-1").read_bytes() == GCODE
    assert not list(tmp_path.glob("*.part"))


def test_out_of_order_wrong_hash_and_too_large_are_refused(tmp_path: Path) -> None:
    store = UploadStore(tmp_path, max_bytes=10_000)
    first, second, *_ = _chunks(GCODE[:5000], "upload-2", 1000)
    with pytest.raises(BadRequest) as err:                       # nothing started
        store.put(second)
    assert err.value.details["field"] == "offset" and err.value.details["expected"] == 0
    store.put(first)
    store.put(second)
    with pytest.raises(BadRequest) as err:                       # the same piece again
        store.put(second)
    assert err.value.details["expected"] == 2000
    bad = _chunks(GCODE[:5000], "upload-3", 5000)[0]
    with pytest.raises(BadRequest) as err:
        store.put(s.UploadChunk(upload_id="upload-3", offset=0, total_bytes=5000, data=bad.data, sha256="0" * 64))
    assert err.value.details["field"] == "sha256" and not (tmp_path / "upload-3.part").exists()
    with pytest.raises(NotFound):
        store.path("upload-3")
    with pytest.raises(ValidationError) as err:
        store.put(s.UploadChunk(upload_id="upload-4", offset=0, total_bytes=10_001, data=b""))
    assert err.value.details["field"] == "total_bytes"
    with pytest.raises(ValidationError) as err:
        store.put(s.UploadChunk(upload_id="../etc", offset=0, total_bytes=1, data=b"x"))
    assert err.value.details["field"] == "upload_id"
    with pytest.raises(ValidationError) as err:
        store.put(s.UploadChunk(upload_id="upload-5", offset=0, total_bytes=10_000,
                                data=b"x" * (UPLOAD_CHUNK_MAX_BYTES + 1)))
    assert err.value.details["field"] == "data"


def test_abandoned_uploads_do_not_pile_up(tmp_path: Path) -> None:
    store = UploadStore(tmp_path, max_bytes=1 << 20, max_open=2)
    for k in range(5):
        store.put(_chunks(GCODE, f"abandoned-{k}", 1000)[0])           # started, never finished
        for c in _chunks(b"%d" % k * 100, f"finished-{k}", 1000):
            store.put(c)
    assert len(list(tmp_path.glob("*.part"))) <= 2 and len(list(tmp_path.glob("*.input"))) == 2
    UploadStore(tmp_path, max_bytes=1 << 20)                             # a restart: partial ones go
    assert not list(tmp_path.glob("*.part"))


# -- the client's checks, before reading ------------------------------------------------------------
def test_sizes_are_checked_before_reading(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    huge = tmp_path / "huge.gcode"
    with open(huge, "wb") as f:                  # sparse: 600 MB that take no disk
        f.truncate(600 << 20)
    with pytest.raises(ValidationError) as err:
        read_input(str(huge))
    assert err.value.details["field"] == "size" and "512 MiB" in str(err.value) and "huge.gcode" in str(err.value)
    with pytest.raises(ValidationError):
        read_whole(str(huge))
    model = tmp_path / "part.stl"
    with open(model, "wb") as f:
        f.truncate(300 << 20)
    with pytest.raises(ValidationError) as err:
        read_input(str(model))
    assert "256 MiB" in str(err.value)
    assert isinstance(read_input(str(huge), max_size_mb=1000), LargeInput)   # a larger limit: sent in pieces
    monkeypatch.setenv(LIMIT_ENV, "0.001")
    small = tmp_path / "small.gcode"
    small.write_bytes(GCODE)
    with pytest.raises(ValidationError):
        read_input(str(small))
    monkeypatch.setenv(LIMIT_ENV, "lots")
    with pytest.raises(ConfigError):
        read_input(str(small))
    with pytest.raises(BadRequest):
        input_size(tmp_path / "missing.gcode", 1 << 20)
    with pytest.raises(BadRequest):
        input_size(tmp_path, 1 << 20)


def test_small_inputs_travel_inline_large_ones_as_uploads(tmp_path: Path) -> None:
    small = tmp_path / "a.gcode"
    small.write_bytes(GCODE)
    assert read_input(str(small)) == GCODE
    big = tmp_path / "b.gcode"
    big.write_bytes(GCODE * (INLINE_MAX_BYTES // len(GCODE) + 1))
    assert isinstance(read_input(str(big)), LargeInput)


# -- through the services ------------------------------------------------------------------------------
def test_an_uploaded_gcode_plans_like_the_inline_one(session, settings, tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    planner = PlannerService(session, settings.cell, Cell.builtin("irb140"))
    planner.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("planner",), deadline_s=20)
            path = tmp_path / "part.gcode"
            path.write_bytes(GCODE)
            sent: list[int] = []
            call = client.call

            def spy(service, command, request=None, timeout=None):
                if command == "upload":
                    sent.append(len(request.data))
                return call(service, command, request, timeout)

            monkeypatch.setattr(client, "call", spy)
            uid = client.upload("planner", path, 1 << 20, chunk_bytes=4096)
            assert len(sent) == -(-len(GCODE) // 4096) and max(sent) <= 4096        # pieces, never the whole
            ids = []
            for source in ({"upload_id": uid}, gcode_source(client, GCODE)):
                acc = client.plan(s.PlanRequest(filename="part.gcode", **source))
                ids.append(client.wait_job("planner", acc.job_id, timeout=60).result_id)
            assert ids[0] == ids[1]
            assert client.plan_summary(ids[0]).material_source == "gcode"
            with pytest.raises(NotFound):
                client.plan(s.PlanRequest(upload_id="nosuchupload"))
            with pytest.raises(ValidationError):
                client.upload("planner", path, 100)                               # over the caller's limit
    finally:
        planner.close()


def test_an_uploaded_model_slices_like_the_inline_one(session, settings, tmp_path: Path) -> None:
    slicer = SlicerService(session, settings.cell, (250.0, 250.0), 250.0)
    slicer.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("slicer",), deadline_s=20)
            model = trimesh.creation.box((20, 20, 3)).export(file_type="stl")
            path = tmp_path / "box.stl"
            path.write_bytes(model)
            uid = client.upload("slicer", path, 1 << 20, chunk_bytes=1000)
            ids = []
            for source in ({"model": b"", "upload_id": uid}, {"model": model}):
                acc = client.slice(s.SliceRequest(filename="box.stl", **source))
                ids.append(client.wait_job("slicer", acc.job_id, timeout=60).result_id)
            assert ids[0] == ids[1]
    finally:
        slicer.close()
