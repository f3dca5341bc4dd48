"""The station's store: events and clock per tick, incremental bead chunks, and a crash at any tick
restored from the last checkpoint to the exact bead list of an uninterrupted run."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fabric import schemas as s
from fabric.motion.program import Program
from fabric.motion.testprog import square_program
from fabric.robot.cell import Cell
from fabric.sim.twin import Twin
from fabric.store.station import StationStore


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


@pytest.fixture(scope="module")
def prog(cell: Cell) -> Program:
    return square_program(cell, size_mm=20, layers=4, layer_height_mm=0.5, speed_mm_s=30)


def event_msg(e) -> s.Event:
    return s.Event(seq=e.seq, t_sim_s=e.t_sim_s, kind=e.kind, row=e.row, gcode_line=e.gcode_line,
                   layer=e.layer, data=dict(e.data))


def test_a_station_at_rest_moves_its_clock_mark_once_a_second_and_every_event_at_once(tmp_path: Path,
                                                                                     monkeypatch) -> None:
    """An idle station wrote its clock mark 50 times a second. At rest (nothing moves, no print runs) a tick
    without events moves it at most every REST_MARK_S; a tick with events, or any tick of a print, writes."""
    from fabric.store import journal as jr
    from fabric.store.artifacts import ArtifactStore
    now = [100.0]
    monkeypatch.setattr(jr.time, "monotonic", lambda: now[0])
    store = StationStore(tmp_path / "station.sqlite")
    journal = jr.StationJournal(store, ArtifactStore(tmp_path / "artifacts"))
    journal.record_tick([], 1.0, at_rest=True)
    assert store.clock_mark() == 1.0                            # the first mark
    for k in range(1, 40):                                     # 0.78 s of 20 ms ticks at rest: no writes
        now[0] += 0.02
        journal.record_tick([], 1.0 + 0.02 * k, at_rest=True)
    assert store.clock_mark() == 1.0
    journal.record_tick([s.Event(seq=1, t_sim_s=1.8, kind="temp_reached")], 1.8, at_rest=True)
    assert store.clock_mark() == 1.8 and store.last_seq() == 1     # an event goes at once, with the mark
    now[0] += jr.REST_MARK_S
    journal.record_tick([], 2.8, at_rest=True)
    assert store.clock_mark() == 2.8                            # a second on: the mark moves
    now[0] += 0.02
    journal.record_tick([], 2.82, at_rest=False)
    assert store.clock_mark() == 2.82                           # moving or printing: every tick


def test_events_and_clock_survive_a_reopen_and_are_pruned(tmp_path: Path) -> None:
    store = StationStore(tmp_path / "station.sqlite", keep_events=1500)
    assert store.last_seq() == 0 and store.clock_mark() is None and store.load() is None
    for k in range(3):
        evs = [s.Event(seq=1000 * k + i + 1, t_sim_s=float(i), kind="layer") for i in range(1000)]
        store.record_tick(evs, t_sim_s=10.0 * (k + 1))
    again = StationStore(tmp_path / "station.sqlite")
    assert again.last_seq() == 3000 and again.clock_mark() == 30.0
    got = again.events(since_seq=2990, limit=5)
    assert [e.seq for e in got] == [2991, 2992, 2993, 2994, 2995]
    first = again.events(since_seq=0, limit=1)[0].seq
    assert 1 < first <= 3000 - 1500 + 1                      # old events pruned (in batches of 1000)


def test_beads_are_appended_in_chunks_and_reset_by_a_new_job(tmp_path: Path, cell: Cell, prog: Program) -> None:
    store = StationStore(tmp_path / "station.sqlite")
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    sizes = []
    while twin.state == "printing":
        twin.advance(0.5)
        store.save_checkpoint(twin.snapshot(with_beads=False), "job-1", twin.beads)
        sizes.append(len(twin.beads))
    ck = StationStore(tmp_path / "station.sqlite").load()
    assert ck is not None and len(ck.beads["row"]) == len(twin.beads) == sizes[-1] > 0
    np.testing.assert_array_equal(ck.beads["end_mm"], twin.beads.end_mm)
    with store.db.read() as conn:
        chunks = conn.execute("SELECT COUNT(*) FROM beads").fetchone()[0]
    assert 1 < chunks <= len(set(sizes))                                    # appended, never rewritten whole
    fresh = Twin(cell)
    fresh.load(prog)
    store.save_checkpoint(fresh.snapshot(with_beads=False), "job-2", fresh.beads)
    assert len(store.load().beads) == 0 or len(store.load().beads["row"]) == 0


@pytest.mark.parametrize("seed", range(6))
def test_crash_at_a_random_tick_restores_and_recovers_exactly(tmp_path: Path, cell: Cell, prog: Program,
                                                              seed: int) -> None:
    ref = Twin(cell)
    ref.load(prog)
    ref.start()
    while ref.state == "printing":
        ref.advance(1.0)
    rng = np.random.default_rng(seed)
    tick_s = 0.02 * float(rng.uniform(1.0, 50.0))          # any real-time factor
    crash_tick = int(rng.integers(5, int(ref.time_info().total_s / tick_s) - 2))
    every = int(rng.integers(1, 40))                        # checkpoint cadence in ticks

    path = tmp_path / "station.sqlite"
    store = StationStore(path)
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    store.save_checkpoint(twin.snapshot(with_beads=False), "job", twin.beads)
    for tick in range(crash_tick):
        events = twin.advance(tick_s)
        store.record_tick([event_msg(e) for e in events], twin.t_sim_s)
        if tick % every == 0:
            store.save_checkpoint(twin.snapshot(with_beads=False), "job", twin.beads)
    last_seq = store.last_seq()
    del twin, store                                          # kill -9: nothing else is written

    store = StationStore(path)
    ck = store.load()
    back = Twin.from_snapshot(cell, ck.state, prog, ck.beads)
    replay = back.advance(ck.t_mark_s - back.t_sim_s)
    assert all(e.seq <= last_seq for e in replay)           # what it re-emits was already logged
    assert back.t_sim_s == pytest.approx(ck.t_mark_s, abs=1e-9)
    back.interrupt("station restarted")
    if back.state == "interrupted":
        back.recover()
    while back.state == "printing":
        back.advance(1.0)
    a, b = back.beads.to_arrays(), ref.beads.to_arrays()
    assert len(a["row"]) == len(b["row"])
    np.testing.assert_allclose(a["start_mm"], b["start_mm"], atol=1e-6, rtol=0)
    np.testing.assert_allclose(a["end_mm"], b["end_mm"], atol=1e-6, rtol=0)
    np.testing.assert_allclose(a["volume_mm3"], b["volume_mm3"], rtol=1e-9, atol=0)
