"""A station started with another cell than the one its saved twin was of: the twin is not restored.

Found driving the cell: ``fabric-cli up --cell-config irb140-multiaxis`` on a machine whose default data folder
held the IRB 140 cell's last checkpoint brought the twin back at the IRB 140's home joints (not a pose of this
cell at all), and a curved dome planned from there was refused as a joint jump. A checkpoint now names the
cell it is of (:meth:`Cell.fingerprint`); another cell's is not restored.
"""
from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fabric.client import Client
from fabric.robot.cell import Cell
from fabric.sim.twin import Twin
from fabric.store.artifacts import ArtifactStore
from fabric.store.journal import StationJournal, StationMeta
from fabric.store.station import StationStore

pytestmark = pytest.mark.timeout(180)


def journal(folder: Path) -> StationJournal:
    return StationJournal(StationStore(folder / "station.sqlite"), ArtifactStore(folder / "artifacts"))


def test_the_fingerprint_tells_cells_apart_and_ignores_their_words() -> None:
    a, b = Cell.builtin("irb140"), Cell.builtin("irb140-multiaxis")
    assert a.fingerprint() == Cell.builtin("irb140").fingerprint() != b.fingerprint()
    a.description = "another description"
    assert a.fingerprint() == Cell.builtin("irb140").fingerprint()


def test_another_cells_checkpoint_is_not_restored_but_the_part_on_the_plate_is_still_said(tmp_path) -> None:
    irb140, multi = Cell.builtin("irb140"), Cell.builtin("irb140-multiaxis")
    j = journal(tmp_path)
    meta = StationMeta(rtf=5.0, plate_occupied=True, plate_job_id="j1", plate_mm3=120.0)
    assert j.checkpoint(Twin(irb140), meta, force=True)
    j.store.close()

    same = journal(tmp_path).restore(irb140)
    assert same is not None and same.meta.plate_occupied
    np.testing.assert_allclose(same.twin.pose().q_rad, irb140.home_q_rad)

    other_j = journal(tmp_path)
    other = other_j.restore(multi)
    assert other is not None
    np.testing.assert_allclose(other.twin.pose().q_rad, multi.home_q_rad)       # this cell's home
    assert other.twin.state == "idle" and other.events == []
    assert (other.meta.plate_occupied, other.meta.plate_job_id, other.meta.plate_mm3, other.meta.rtf) == (
        True, "j1", 120.0, 5.0)
    assert other.meta.program_id == "" and other.meta.job_id == ""


def spawn_station(settings, data_dir: Path, log: Path, cell: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "fabric.cli.main", "serve", "station", *settings.to_args(),
           "--data-dir", str(data_dir), "--cell-config", cell]
    return subprocess.Popen(cmd, stdout=open(log, "ab"), stderr=subprocess.STDOUT, start_new_session=True)


def test_a_station_restarted_with_another_cell_starts_at_that_cells_home(hub, settings, tmp_path) -> None:
    log = tmp_path / "station.log"
    station = spawn_station(settings, tmp_path / "data", log, "irb140")
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station",), deadline_s=60)
            np.testing.assert_allclose(client.position().q_deg, np.degrees(Cell.builtin("irb140").home_q_rad),
                                       atol=1e-6)
        station.send_signal(signal.SIGTERM)
        station.wait(timeout=30)
        station = spawn_station(settings, tmp_path / "data", log, "irb140-multiaxis")
        with Client.connect(settings) as client:
            client.wait_alive(("station",), deadline_s=60)
            np.testing.assert_allclose(client.position().q_deg,
                                       np.degrees(Cell.builtin("irb140-multiaxis").home_q_rad), atol=1e-6)
            assert client.state().state == "idle"
    finally:
        station.send_signal(signal.SIGTERM)
        station.wait(timeout=30)
    assert "the last checkpoint is of another cell ('irb140', not 'irb140-multiaxis'" in log.read_text()
