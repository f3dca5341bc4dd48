"""A full disk: work is refused before it starts with a typed `disk_full` error, a disk that fills while
working is `disk_full` too (never `internal`), uploads go once their job ends, and the station's state stays
as it was."""
from __future__ import annotations

import errno

import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.motion.testprog import square_program
from fabric.programs import program_artifact
from fabric.robot.cell import Cell
from fabric.server.disk import RESERVE_ENV, disk_full_of, require_room
from fabric.services.collision import CollisionService
from fabric.services.planner import PlannerService
from fabric.services.station import StationService
from fabric.wire.errors import DiskFull

pytestmark = pytest.mark.timeout(120)

GCODE = ("G21\nG90\nM83\nM104 S200\nM109 S200\nG1 Z0.3 F600\n"
         + "".join(f"G1 X{60 + (k % 40) * 2} Y{60 + k // 40} E0.1 F1800\n" for k in range(400))).encode()
NO_ROOM_MB = str(2**40)          # a reserve no disk has: every service's disk is "full"


def test_room_is_checked_against_the_reserve_and_enospc_is_typed(tmp_path, monkeypatch):
    require_room(tmp_path, 1, "planner", "a test")
    monkeypatch.setenv(RESERVE_ENV, NO_ROOM_MB)
    with pytest.raises(DiskFull, match="not enough for a test") as err:
        require_room(tmp_path, 1, "planner", "a test")
    assert err.value.code == "disk_full" and err.value.details["path"] == str(tmp_path)
    assert disk_full_of(OSError(errno.ENOSPC, "No space left on device"), "x", tmp_path).code == "disk_full"
    assert disk_full_of(OSError(errno.EACCES, "denied"), "x", tmp_path) is None


def test_a_full_disk_refuses_plans_and_uploads_and_an_upload_goes_with_its_job(session, settings, tmp_path,
                                                                              monkeypatch):
    planner = PlannerService(session, settings.cell, Cell.builtin("irb140"), data_dir=tmp_path / "planner")
    planner.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("planner",), deadline_s=20)
            path = tmp_path / "part.gcode"
            path.write_bytes(GCODE)
            uid = client.upload("planner", path, 1 << 20)
            assert len(list((tmp_path / "planner" / "uploads").glob("*.input"))) == 1
            done = client.wait_job("planner", client.plan(s.PlanRequest(filename="p.gcode", upload_id=uid)).job_id,
                                   timeout=60)
            assert done.state == "done"
            assert list((tmp_path / "planner" / "uploads").iterdir()) == []      # used: removed
            monkeypatch.setenv(RESERVE_ENV, NO_ROOM_MB)                           # the disk fills up
            with pytest.raises(DiskFull, match=r"planner has .* MiB free"):
                client.plan(s.PlanRequest(filename="p.gcode", gcode=GCODE))
            with pytest.raises(DiskFull):
                client.upload("planner", path, 1 << 20)
            assert list((tmp_path / "planner" / "uploads").iterdir()) == []
            monkeypatch.delenv(RESERVE_ENV)

            def no_space(*_a, **_k):                                               # full while writing
                raise OSError(errno.ENOSPC, "No space left on device")
            monkeypatch.setattr(planner.artifacts, "put_encoded", no_space)
            with pytest.raises(DiskFull, match="ran out of disk space"):
                client.wait_job("planner", client.plan(s.PlanRequest(filename="q.gcode",
                                                                     gcode=GCODE + b"G1 X1\n")).job_id, timeout=60)
            assert client.health("planner").state == "ok"          # a job's full disk is the job's error
    finally:
        planner.close()


def test_a_load_that_does_not_fit_leaves_the_station_as_it_was(session, settings, tmp_path, monkeypatch):
    cell = Cell.builtin("irb140")
    planner = PlannerService(session, settings.cell, cell)
    collision = CollisionService(session, settings.cell, cell)
    station = StationService(session, settings.cell, cell, data_dir=tmp_path / "station")
    pid = planner.store_artifact(program_artifact(square_program(cell, size_mm=20, layers=2, nozzle_c=200.0)))
    for svc in (planner, collision, station):
        svc.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station", "collision", "planner"), deadline_s=20)
            before = client.state()
            monkeypatch.setenv(RESERVE_ENV, NO_ROOM_MB)
            with pytest.raises(DiskFull, match="keeping the program"):
                client.load(pid)
            after = client.state()
            assert (after.state, after.program_id) == (before.state, before.program_id) == ("idle", "")
            monkeypatch.delenv(RESERVE_ENV)
            assert client.load(pid).total_s > 0 and client.state().program_id == pid
    finally:
        for svc in (station, collision, planner):
            svc.close()
