"""Owned state, enforced: the fields only a service's writer may touch raise when another thread does, in the
station and the supervisor; every station change is checkpointed by the command mechanism, never by hand."""
from __future__ import annotations

import ast
import threading
from pathlib import Path

import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.robot.cell import Cell
from fabric.server.writer import Owned, OwnershipError, Writer
from fabric.services.station import StationService
from fabric.services.supervisor import SupervisorService
from fabric.wire.errors import StateError

pytestmark = pytest.mark.timeout(120)
SERVICES = Path(__file__).resolve().parents[1] / "fabric" / "services"
BY_HAND = ("writer.call", "_step", "journal.checkpoint", "_checkpoint")     # what only the command runner calls


class _Counter:
    value: Owned[int] = Owned()

    def __init__(self) -> None:
        self.writer = Writer("counter")
        self.value = 0                                  # before the writer runs: the constructing thread may


def test_an_owned_field_is_the_writers_alone_while_it_runs() -> None:
    c, stop = _Counter(), threading.Event()
    worker = threading.Thread(target=c.writer.run, args=(stop, 0.02), name="counter:writer", daemon=True)
    worker.start()
    try:
        assert c.writer.call(lambda: c.value) == 0        # the writer's thread reads it (it has run a step now)
        c.writer.call(lambda: setattr(c, "value", 5))
        with pytest.raises(OwnershipError, match="counter's writer, but thread 'MainThread' touched it"):
            _ = c.value
        with pytest.raises(OwnershipError):
            c.value = 6
        seen: list[BaseException] = []

        def other() -> None:
            try:
                c.value += 1
            except OwnershipError as exc:
                seen.append(exc)
        t = threading.Thread(target=other, name="intruder")
        t.start()
        t.join()
        assert len(seen) == 1 and "'intruder'" in str(seen[0])
        assert c.writer.call(lambda: c.value) == 5          # nothing changed
    finally:
        stop.set()
        worker.join(5)
        c.writer.close()
    assert c.value == 5                                      # closed: the closing thread may read it again


@pytest.fixture
def station(session, settings):
    st = StationService(session, settings.cell, Cell.builtin("irb140"))
    st.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station",), deadline_s=20)
            yield st, client
    finally:
        st.close()


def test_the_station_twin_and_record_are_its_clocks_alone(station) -> None:
    st, client = station
    client.state()                                           # the clock has run steps: it is the writer
    for name in ("twin", "meta", "collision_report"):
        with pytest.raises(OwnershipError, match=f"StationService.{name} belongs to station's writer"):
            getattr(st, name)
    assert st.commands.read(lambda: st.twin.state) == "idle"      # a step may
    with pytest.raises(OwnershipError):
        st.meta = st.commands.read(lambda: st.meta)               # nor replaced from outside


def test_a_change_is_checkpointed_by_the_mechanism_and_a_refusal_is_not(station, monkeypatch) -> None:
    st, client = station
    taken: list[bool] = []
    real = st.journal.checkpoint

    def counting(twin, meta, force=False):
        if force:
            taken.append(True)
        return real(twin, meta, force=force)
    monkeypatch.setattr(st.journal, "checkpoint", counting)
    with pytest.raises(StateError):
        client.pause()                                        # nothing to pause: refused, nothing written
    assert taken == []
    before = st.commands.read(lambda: st.commands.generation)
    client.overrides(speed_r=1.5)
    assert taken == [True] and st.commands.read(lambda: st.commands.generation) == before + 1
    st.commands.change(lambda: None)                          # any change, even one of a new command
    assert len(taken) == 2


def test_no_station_command_steps_or_checkpoints_by_hand() -> None:
    """Only the command runner calls the writer and takes the checkpoint: a command of station.py or of a
    registered module that called ``writer.call`` or ``journal.checkpoint`` itself could skip a part."""
    for path in SERVICES.glob("station*.py"):
        if path.name == "station_commands.py":
            continue
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef) and (node.name.startswith(("on_", "cmd_")) or node.name == "act"):
                calls = {ast.unparse(n.func) for n in ast.walk(node) if isinstance(n, ast.Call)}
                by_hand = {c for c in calls if c.endswith(BY_HAND)}
                assert not by_hand, f"{path.name}:{node.lineno} {node.name} steps or checkpoints by hand: {by_hand}"


def test_the_supervisors_records_and_fields_are_its_writers_alone(session, settings) -> None:
    sup = SupervisorService(session, settings.cell)
    sup.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("supervisor",), deadline_s=20)
            client.jobs()
            sup.writer.call(lambda: None)                     # the writer has run
            rec = s.JobRecord(job_id="x1", filename="a.gcode", source="gcode", profile="", backend="builtin",
                              model_id="0" * 64, state="queued", stage="queued", created_s=0.0, updated_s=0.0)
            with pytest.raises(OwnershipError, match="a change of the job records belongs to supervisor's writer"):
                sup.store.add(rec)
            with pytest.raises(OwnershipError):
                sup.store.set_plate_clear(False)
            for name in ("_loading", "_plate_epoch", "_seen"):
                with pytest.raises(OwnershipError):
                    getattr(sup, name)
            assert sup.store.count() == 0 and sup.store.plate_clear()     # reads are free; nothing changed
            sup.writer.call(lambda: sup.store.add(rec))                    # a step may
            assert client.job("x1").state == "queued"
    finally:
        sup.close()
