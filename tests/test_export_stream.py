"""Streamed exports: the planner's export_chunk endpoint, its typed errors, and all-or-nothing export files."""
from __future__ import annotations

import io

import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.planning.post.atomic import AtomicFiles
from fabric.planning.post.stream import ExportStream
from fabric.robot.cell import Cell
from fabric.services.planner import PlannerService
from fabric.wire.errors import BadRequest, FabricError, NotFound, UnreachableError, ValidationError

pytestmark = pytest.mark.timeout(120)

_GCODE = "\n".join(["G21", "G90", "M83", "M104 S200", "M109 S200", "G1 Z0.3 F600"]
                   + [f"G1 X{60 + (k % 40) * 2} Y{60 + k // 40} E0.1 F1800" for k in range(1200)]) + "\n"


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


@pytest.fixture
def planned(session, settings, cell):
    """A planner in this process with one planned program; yields (client, program id)."""
    planner = PlannerService(session, settings.cell, cell)
    planner.start()
    with Client.connect(settings) as client:
        client.wait_alive(("planner",), deadline_s=20)
        acc = client.plan(s.PlanRequest(gcode=_GCODE.encode(), filename="grid.gcode"))
        st = client.wait_job("planner", acc.job_id, timeout=60)
        yield client, st.result_id
    planner.close()


@pytest.mark.parametrize("fmt", ["csv", "rapid", "krl", "urscript"])
def test_chunks_join_to_the_whole_export(planned, fmt: str) -> None:
    client, pid = planned
    whole = client.export(pid, fmt, module_targets=300).data
    out = io.BytesIO()
    n = client.export_to(pid, fmt, out, module_targets=300, limit_bytes=4096)     # many small chunks
    assert n == len(whole) > 4096 * 3 and out.getvalue() == whole


def test_bad_offsets_and_ids_are_typed_errors(planned) -> None:
    client, pid = planned
    first = client.export_chunk(pid, "csv", 0, 4096)
    assert first.offset == 0 and len(first.data) == 4096 and not first.done and first.name.endswith(".csv")
    with pytest.raises(BadRequest):            # not where the stream stands
        client.export_chunk(pid, "csv", 10, 4096)
    with pytest.raises(BadRequest):            # nothing started for this format
        client.export_chunk(pid, "krl", 4096, 4096)
    with pytest.raises(NotFound):
        client.export_chunk("0" * 64, "csv", 0, 4096)
    with pytest.raises(NotFound):
        client.export_chunk("0" * 64, "csv", 4096, 4096)
    with pytest.raises(ValidationError):
        client.export_chunk(pid, "csv", -1, 4096)
    with pytest.raises(ValidationError):
        client.export_chunk(pid, "gcode", 0, 4096)
    # a restart at offset 0 gives the same bytes again
    assert client.export_chunk(pid, "csv", 0, 4096).data == first.data


def test_unreachable_program_exports_only_csv(session, settings, cell) -> None:
    planner = PlannerService(session, settings.cell, cell)
    planner.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("planner",), deadline_s=20)
            far = "G21\nG90\nM83\nG1 Z0.3 F600\nG1 X100 Y100 E1\nG1 X2000 Y100 E5\n"
            st = client.wait_job("planner", client.plan(s.PlanRequest(gcode=far.encode())).job_id, timeout=60)
            with pytest.raises(UnreachableError):
                client.export_chunk(st.result_id, "rapid", 0)
            assert client.export_to(st.result_id, "csv", io.BytesIO()) > 0
    finally:
        planner.close()


@pytest.mark.parametrize("fmt", ["csv", "rapid"])
def test_export_by_job_id_starts_before_the_job_ends(session, settings, cell, fmt: str) -> None:
    """Asked for by job id right after the plan is accepted: the same bytes as the export by program id."""
    planner = PlannerService(session, settings.cell, cell)
    planner.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("planner",), deadline_s=20)
            acc = client.plan(s.PlanRequest(gcode=_GCODE.encode(), filename="grid.gcode"))
            early = io.BytesIO()
            client.export_to("", fmt, early, module_targets=300, limit_bytes=4096, job_id=acc.job_id)
            st = client.wait_job("planner", acc.job_id, timeout=60)
            assert early.getvalue() == client.export(st.result_id, fmt, module_targets=300).data
            last = client.export_chunk("", fmt, 0, 1 << 20, 300, job_id=acc.job_id)
            assert last.program_id == st.result_id and last.name == f"grid.{'csv' if fmt == 'csv' else 'mod'}"
            with pytest.raises(NotFound):
                client.export_chunk("", fmt, 0, job_id="0" * 12)
            bad = client.plan(s.PlanRequest(gcode=b"G21\nG90\nG1 X1.2.3 Y4\n"))    # the job's error, typed
            with pytest.raises(FabricError) as err:
                client.export_to("", fmt, io.BytesIO(), job_id=bad.job_id)
            assert err.value.code == "gcode"
    finally:
        planner.close()


def test_writer_failure_reaches_the_reader() -> None:
    def write(out) -> None:
        out.write("x" * 10_000)
        raise ValidationError("bad program", field="program")

    stream = ExportStream(write, piece_bytes=4096)
    got = b""
    with pytest.raises(ValidationError):
        while not stream.done:
            got += stream.read(len(got), 4096)
    assert len(got) <= 10_000


def test_atomic_files_all_or_nothing(tmp_path) -> None:
    a, b = tmp_path / "a.csv", tmp_path / "b.mod"
    b.write_text("old")
    with pytest.raises(RuntimeError), AtomicFiles() as files:
        files.open(a).write(b"new a")
        files.open(b).write(b"new b")
        raise RuntimeError("export failed half way")
    assert not a.exists() and b.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.mod"]       # no temporary file left
    with AtomicFiles() as files:
        files.open(a).write(b"new a")
        files.open(b).write(b"new b")
    assert a.read_bytes() == b"new a" and b.read_bytes() == b"new b"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "b.mod"]


def test_export_by_the_id_of_an_older_job_whose_program_was_let_go(session, settings, cell) -> None:
    """Two plans later the first job's hand-off is released (the planner keeps the last plan's): an export by
    its job id still gives its program, from the store (the job is ``done``: a plan job's states are
    queued, running, done and failed, not a print job's)."""
    planner = PlannerService(session, settings.cell, cell)
    planner.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("planner",), deadline_s=20)
            first = client.plan(s.PlanRequest(gcode=_GCODE.encode(), filename="grid.gcode"))
            done = client.wait_job("planner", first.job_id, timeout=60)
            assert done.state == "done"
            for k in range(2):
                later = client.plan(s.PlanRequest(gcode=_GCODE.replace("E0.1", f"E0.{k + 2}").encode()))
                client.wait_job("planner", later.job_id, timeout=60)
            chunk = client.export_chunk("", "csv", 0, 1 << 20, 300, job_id=first.job_id)
            assert chunk.done and chunk.data == client.export(done.result_id, "csv").data
    finally:
        planner.close()
