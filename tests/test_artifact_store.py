"""Artifacts on disk: atomic, verified on read, bounded with LRU eviction that spares pinned ones."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fabric.programs import content_id
from fabric.schemas import Artifact
from fabric.store.artifacts import ArtifactStore
from fabric.wire.errors import NotFound, ValidationError


def art(data: bytes, name: str = "a.gcode") -> Artifact:
    return Artifact(artifact_id=content_id(data), name=name, media_type="text/x-gcode", data=data)


def test_put_get_and_survive_a_reopen(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path)
    a = art(b"G1 X1\n" * 100)
    assert store.put(a) == a.artifact_id
    assert store.put(a) == a.artifact_id                       # idempotent
    again = ArtifactStore(tmp_path)                            # a restarted service
    got = again.get(a.artifact_id)
    assert got.data == a.data and got.name == "a.gcode" and got.media_type == "text/x-gcode"
    assert again.ids() == [a.artifact_id] and again.total_bytes() > len(a.data)


def test_wrong_id_and_malformed_id_are_refused(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path)
    bad = Artifact(artifact_id=content_id(b"x"), name="x", media_type="t", data=b"y")
    with pytest.raises(ValidationError, match="sha256"):
        store.put(bad)
    with pytest.raises(ValidationError, match="hex digest"):
        store.get("../../etc/passwd")
    with pytest.raises(NotFound):
        store.get(content_id(b"never stored"))
    assert store.ids() == []


def test_damaged_file_is_removed_and_reported(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path)
    a = art(b"G1 X2\n" * 50)
    store.put(a)
    path = tmp_path / a.artifact_id[:2] / a.artifact_id
    raw = bytearray(path.read_bytes())
    raw[-3] ^= 0xFF                                            # flip a bit of the data
    path.write_bytes(bytes(raw))
    with pytest.raises(NotFound, match="damaged"):
        store.get(a.artifact_id)
    assert not path.exists() and store.ids() == []
    path.parent.mkdir(exist_ok=True)
    path.write_bytes(b"\x00garbage")                           # not even msgpack
    store2 = ArtifactStore(tmp_path)
    with pytest.raises(NotFound, match="damaged"):
        store2.get(a.artifact_id)


def test_eviction_is_lru_and_never_removes_pinned(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path, max_bytes=3500)
    arts = [art(bytes([i]) * 900, f"{i}") for i in range(3)]
    for a in arts:
        store.put(a)
    store.pin(arts[0].artifact_id, "job-1")                    # the oldest, but a queued job needs it
    store.get(arts[1].artifact_id)                             # recently used
    extra = art(b"z" * 900)
    store.put(extra)
    ids = set(store.ids())
    assert arts[0].artifact_id in ids and extra.artifact_id in ids
    assert arts[2].artifact_id not in ids                      # least recently used, unpinned
    assert store.total_bytes() <= 3500
    store.unpin("job-1")
    store.put(art(b"w" * 900))
    assert arts[0].artifact_id not in store.ids()              # no longer protected
    assert ArtifactStore(tmp_path, max_bytes=3500).pinned() == set()


def test_pins_survive_a_restart_and_stray_temp_files_are_cleaned(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path)
    a = art(b"keep me")
    store.put(a)
    store.pin(a.artifact_id, "job-7")
    stray = tmp_path / a.artifact_id[:2] / ".tmp-crashed"
    stray.write_bytes(b"half a write")
    again = ArtifactStore(tmp_path)
    assert again.pinned() == {a.artifact_id} and not stray.exists()


def test_index_rebuilt_from_files(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path)
    a = art(b"indexed")
    store.put(a)
    del store
    (tmp_path / "index.sqlite").unlink()
    for side in ("index.sqlite-wal", "index.sqlite-shm"):
        (tmp_path / side).unlink(missing_ok=True)
    again = ArtifactStore(tmp_path)
    assert again.ids() == [a.artifact_id] and again.get(a.artifact_id).data == b"indexed"


def test_a_program_stored_from_pieces_reads_back_as_the_whole_artifact(tmp_path: Path) -> None:
    """The planner stores million-row programs from their columns (no copy of the whole): the file,
    the id and what a reader gets are those of ``program_artifact``."""
    from fabric.motion.testprog import square_program
    from fabric.programs import program_artifact, program_artifact_pieces, program_from_artifact
    from fabric.robot.cell import Cell
    program = square_program(Cell.builtin("irb140"), layers=2)
    whole = program_artifact(program, name="sq.program")
    artifact_id, pieces = program_artifact_pieces(program, name="sq.program")
    assert artifact_id == whole.artifact_id
    store = ArtifactStore(tmp_path)
    assert store.put_encoded(artifact_id, pieces) == artifact_id
    got = ArtifactStore(tmp_path).get(artifact_id)             # read back (hash verified) after a restart
    assert got == whole
    assert np.array_equal(program_from_artifact(got).q_rad, program.q_rad)
    with pytest.raises(ValidationError):
        store.put_encoded("not-an-id", pieces)
