"""Cold extrusion is refused by the plan, naming the line (not only by the twin's interlock at print time),
the job fails in preparation with that reason, and a pause by the interlock says so in the job's record."""
from __future__ import annotations

import threading
from dataclasses import replace

import pytest

from fabric import schemas as s
from fabric.cli.main import main
from fabric.client import Client
from fabric.motion.program import NOZZLE, SET_TEMP, WAIT_TEMP
from fabric.planning import plan_gcode
from fabric.printjobs.events import apply_event
from fabric.printjobs.prepare import Preparer
from fabric.programs import content_id
from fabric.robot.cell import Cell
from fabric.services.planner import PlannerService
from fabric.services.station import StationService
from fabric.sim.twin import Twin
from fabric.store.artifacts import ArtifactStore
from fabric.wire.errors import ColdExtrusionError

pytestmark = pytest.mark.timeout(180)

PLA = "; filament_type = PLA\n; min_extrude_temp_c = 170\n; filament_diameter = 2.85\nG21\nG90\nM83\n"   # 6 lines
MOVES = "G1 X100 Y100 Z0.3 F3000\nG1 X120 Y100 E1 F1200\nG1 X120 Y120 E1\nG1 X100 Y120 E1\n"


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


def test_a_set_point_below_the_minimum_makes_the_plan_not_runnable_naming_the_line(cell: Cell) -> None:
    res = plan_gcode(PLA + "M104 S120\nM109 S120\n" + MOVES, cell)       # lines 7, 8; first extrusion: line 10
    assert res.report.reachable and not res.report.runnable
    cold = res.report.cold
    assert (cold.gcode_line, cold.reason, cold.nozzle_c, cold.set_line, cold.min_c) == (
        10, "set below the minimum", 120.0, 7, 170.0)
    with pytest.raises(ColdExtrusionError) as err:
        res.require_runnable()
    assert err.value.code == "cold_extrusion" and err.value.details["gcode_line"] == 10
    assert str(err.value) == ("G-code line 10 extrudes with the nozzle set to 120 C (line 7), below PLA's minimum "
                              "extrusion temperature 170 C")


@pytest.mark.parametrize("temps, line, reason, words", [
    ("M109 S120\n", 9, "set below the minimum", "set to 120 C (line 7)"),      # the wait's own set point
    ("", 8, "set below the minimum", "nozzle heater off (no M104/M109 before it)"),
    ("M104 S200\n", 9, "not heated", "nothing waits for it to heat"),        # the twin would reach it cold
    ("M109 S120\nM104 S200\n", 10, "not heated", "the last wait (line 7) was for 120 C"),
    ("M109 S210\nM104 S0\n", 10, "set below the minimum", "heater off (M104 S0 at line 8)"),
])
def test_every_way_to_extrude_cold_names_its_line(cell: Cell, temps: str, line: int, reason: str,
                                                   words: str) -> None:
    cold = plan_gcode(PLA + temps + MOVES, cell).report.cold
    assert cold is not None and (cold.gcode_line, cold.reason) == (line, reason) and words in cold.message


def test_a_minimum_the_gcode_does_not_state_is_the_firmware_default_when_it_heats(cell: Cell) -> None:
    head = "; filament_diameter = 2.85\nG21\nG90\nM83\n"
    cold = plan_gcode(head + "M104 S150\nM109 S150\n" + MOVES, cell).report.cold
    assert cold is not None and cold.min_c == 170.0 and "the G-code states none" in cold.message
    assert plan_gcode(head + MOVES, cell).report.runnable            # heats nothing: clay, concrete


def test_hot_enough_and_waited_for_is_runnable_and_the_twin_prints_it(cell: Cell) -> None:
    for temps in ("M104 S205\nM109 S205\n", "M109 S205\n", "M109 S215\nM104 S205\n"):
        res = plan_gcode(PLA + temps + MOVES, cell).require_runnable()
        assert res.report.cold is None
        twin = Twin(cell)
        twin.load(res.program)
        twin.start()
        events = []
        for _ in range(10_000):
            events += twin.advance(0.5)
            if twin.state != "printing" and not twin.moving:
                break
        assert twin.state == "idle" and twin.reason == "finished", (temps, twin.reason)
        assert "interlock" not in [e.kind for e in events]


def test_m109_alone_sets_the_set_point_it_waits_for(cell: Cell) -> None:
    """Firmware's M109 S sets the target and waits: the program says so (a SET_TEMP first), so the twin
    heats instead of waiting for a heater that is off and then refusing to extrude."""
    prog = plan_gcode(PLA + "M109 S205\n" + MOVES, cell).program
    rows = [(int(o), float(v)) for o, v, a in zip(prog.op, prog.value, prog.aux, strict=True)
            if o in (SET_TEMP, WAIT_TEMP) and a == NOZZLE]
    assert rows == [(SET_TEMP, 205.0), (WAIT_TEMP, 205.0)]
    prog = plan_gcode(PLA + "M104 S205\nM109 S205\n" + MOVES, cell).program    # set already: no extra row
    assert int(((prog.op == SET_TEMP) & (prog.aux == NOZZLE)).sum()) == 1


def _record(plan: s.PlanSummary | None = None) -> s.JobRecord:
    return s.JobRecord(job_id="j1", filename="part.gcode", source="gcode", state="printing", started_s=1.0,
                       plan=plan)


def test_a_pause_by_the_interlock_is_the_jobs_reason_not_the_operator(cell: Cell) -> None:
    # a program that passes no plan check (loaded by hand): the twin's interlock still catches it
    prog = plan_gcode(PLA + "M104 S120\nM109 S120\n" + MOVES, cell).program
    twin = Twin(cell)
    twin.load(prog)
    twin.start()
    events = []
    for _ in range(10_000):
        events += twin.advance(0.5)
        if twin.state == "paused" and not twin.moving:
            break
    kinds = [e.kind for e in events]
    assert "interlock" in kinds and kinds[-1] == "paused"
    rec = _record()
    for ev in events:
        apply_event(rec, s.Event(seq=ev.seq, t_sim_s=ev.t_sim_s, kind=ev.kind, row=ev.row,
                                 gcode_line=ev.gcode_line, layer=ev.layer, data=dict(ev.data)), 2.0)
    assert rec.state == "paused" and rec.reason.startswith("cold extrusion prevented: the nozzle is at")
    assert "minimum extrusion temperature 170 C" in rec.reason and "operator" not in rec.reason
    # the operator's pause still says it is the operator's
    apply_event(rec, s.Event(seq=99, t_sim_s=1.0, kind="resumed"), 3.0)
    apply_event(rec, s.Event(seq=100, t_sim_s=2.0, kind="paused", data={"reason": "paused by operator"}), 4.0)
    assert rec.reason == "paused by operator"


def test_preparation_fails_the_job_with_the_cold_extrusion(session, settings, cell: Cell, tmp_path, capsys) -> None:
    planner = PlannerService(session, settings.cell, cell, data_dir=tmp_path / "planner")
    station = StationService(session, settings.cell, cell, data_dir=tmp_path / "station")
    for svc in (planner, station):
        svc.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("planner", "station"), deadline_s=20)
            models = ArtifactStore(tmp_path / "models")
            data = (PLA + "M104 S120\nM109 S120\n" + MOVES).encode()
            mid = models.put(s.Artifact(artifact_id=content_id(data), name="part.gcode", media_type="text/x-gcode",
                                        data=data))
            saved: list[s.JobRecord] = []
            rec = s.JobRecord(job_id="cold1", filename="part.gcode", source="gcode", model_id=mid)
            Preparer(client, models, lambda r: saved.append(r), threading.Event(), budget_s=60).prepare(rec)
            assert rec.state == "failed" and rec.error is not None and rec.error.code == "cold_extrusion"
            assert rec.reason == ("cold_extrusion: the program would extrude cold: G-code line 10 extrudes with the "
                                  "nozzle set to 120 C (line 7), below PLA's minimum extrusion temperature 170 C")
            assert rec.error.details["gcode_line"] == 10 and rec.error.details["reason"] == "set below the minimum"
            assert rec.plan is not None and not rec.plan.runnable and rec.plan.cold_extrusion.gcode_line == 10
            # a controller export of it is refused the same way (the CSV, for looking at, is not)
            with pytest.raises(ColdExtrusionError, match="line 10"):
                client.export(rec.program_id, "rapid")
        # and fabric-cli plan says it (exit 2: not runnable)
        path = tmp_path / "part.gcode"
        path.write_bytes(data)
        assert main(["plan", str(path), *replace(settings, mode="client").to_args()]) == 2
        assert ("NOT RUNNABLE: cold extrusion: G-code line 10 extrudes with the nozzle set to 120 C (line 7), below "
                "PLA's minimum extrusion temperature 170 C") in capsys.readouterr().out
    finally:
        for svc in (station, planner):
            svc.close()
