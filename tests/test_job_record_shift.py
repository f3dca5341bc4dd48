"""A job's record over an operator's shift, with the real services in process (issue 24): a print stopped at a
layer and restarted there keeps both runs and its first start; the overrides set during it are in its record and
end with it (the next job starts at x1, and deposits what its plan says)."""
from __future__ import annotations

import queue
import time

import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.robot.cell import Cell
from fabric.services.collision import CollisionService
from fabric.services.planner import PlannerService
from fabric.services.station import StationService
from fabric.services.supervisor import SupervisorService

pytestmark = pytest.mark.timeout(240)


def tower_gcode(layers: int, side_mm: float = 30.0) -> bytes:
    """Square perimeters, layer after layer, as a slicer writes them (no heating: it extrudes cold)."""
    g = "; filament_diameter = 1.75\nG21\nG90\nM83\n"
    for k in range(layers):
        z = 0.4 * (k + 1)
        g += (f";LAYER_CHANGE\n;Z:{z:.2f}\nG1 Z{z:.2f} F600\nG1 X100 Y100 F3000\nG1 X{100 + side_mm} Y100 E1.5 F900\n"
              f"G1 X{100 + side_mm} Y{100 + side_mm} E1.5\nG1 X100 Y{100 + side_mm} E1.5\nG1 X100 Y100 E1.5\n")
    return g.encode()


def wait_job(client: Client, job_id: str, done, timeout_s: float = 60.0) -> s.JobRecord:
    end = time.monotonic() + timeout_s
    while True:
        rec = client.job(job_id)
        if done(rec):
            return rec
        assert time.monotonic() < end, f"job {job_id}: {rec.state} {rec.stage}"
        time.sleep(0.05)


def wait_event(events, kind: str, timeout_s: float = 60.0, layer: int = -1) -> s.Event:
    end = time.monotonic() + timeout_s
    while True:
        try:
            ev = events.get(timeout=max(end - time.monotonic(), 0.01))
        except queue.Empty:
            raise AssertionError(f"no {kind} event") from None
        if ev.kind == kind and ev.layer >= layer:
            return ev


def test_stop_restart_at_a_layer_overrides_and_the_next_job(session, settings, tmp_path):
    cell = Cell.builtin("irb140")
    services = [PlannerService(session, settings.cell, cell, data_dir=tmp_path / "planner"),
                CollisionService(session, settings.cell, cell),
                StationService(session, settings.cell, cell, data_dir=tmp_path / "station"),
                SupervisorService(session, settings.cell, data_dir=tmp_path / "supervisor")]
    for svc in services:
        svc.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station", "collision", "planner", "supervisor"), deadline_s=20)
            events = client.subscribe("station", "events")
            first = client.submit(s.JobSubmit(model=tower_gcode(12), filename="tower.gcode", source="gcode",
                                              start=True, rtf=20.0)).job_id
            wait_event(events, "layer", layer=2)
            client.overrides(speed_r=1.5, flow_r=1.1)                   # the operator speeds it up ...
            wait_event(events, "layer", layer=4)
            client.stop()                                                # ... and stops it at layer 5
            stopped = wait_job(client, first, lambda r: r.state == "stopped")
            assert len(stopped.segments) == 1 and stopped.segments[0].ended == "stopped"
            client.start(rtf=0, from_layer=stopped.layer)               # restart at the layer it stopped in
            rec = wait_job(client, first, lambda r: r.state == "finished")
            one, two = rec.segments
            assert (one.began, one.ended) == ("start", "stopped")
            assert (two.began, two.from_layer, two.ended) == ("restart", stopped.layer, "finished")
            assert rec.started_s == one.started_s < two.started_s and rec.ended_s == two.ended_s
            assert rec.deposited_mm3 == pytest.approx(one.deposited_mm3 + two.deposited_mm3)
            assert rec.sim_elapsed_s == pytest.approx(one.sim_s + two.sim_s)
            (o,) = rec.live_overrides
            assert (o.speed_r, o.flow_r) == (1.5, 1.1) and 2 <= o.layer <= 4
            assert client.state().speed_r == 1.5                        # in force until the job ends

            # the next job: plate cleared, its overrides start at x1, it deposits what its plan says
            second = client.submit(s.JobSubmit(model=tower_gcode(4), filename="small.gcode", source="gcode",
                                               start=True, rtf=0.0)).job_id
            waiting = wait_job(client, second, lambda r: r.prepared and r.waiting_for == "plate")
            assert waiting.state == "queued"
            client.job_next()
            done = wait_job(client, second, lambda r: r.state == "finished")
            assert done.live_overrides == [] and len(done.segments) == 1
            assert done.deposited_mm3 == pytest.approx(done.plan.extruded_mm3, rel=1e-6)
            st = client.state()
            assert (st.speed_r, st.flow_r) == (1.0, 1.0) and st.progress_r == 1.0
            events.close()
    finally:
        for svc in reversed(services):
            svc.close()


def test_a_gcode_job_takes_the_filament_diameter_and_refuses_profile_keys(session, settings, tmp_path, capsys):
    """Issue 24: Cura G-code for 2.85 mm filament states no diameter; job submit had no way to say it, and
    --set filament_diameter_mm=2.85 was accepted, recorded and ignored. Also: job show takes a unique prefix."""
    from dataclasses import replace

    from fabric.cli.main import main
    from fabric.wire.errors import ValidationError

    cell = Cell.builtin("irb140")
    services = [PlannerService(session, settings.cell, cell, data_dir=tmp_path / "planner"),
                CollisionService(session, settings.cell, cell),
                StationService(session, settings.cell, cell, data_dir=tmp_path / "station"),
                SupervisorService(session, settings.cell, data_dir=tmp_path / "supervisor")]
    for svc in services:
        svc.start()
    gcode = tower_gcode(3).replace(b"; filament_diameter = 1.75\n", b"")        # says no diameter, as Cura
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station", "collision", "planner", "supervisor"), deadline_s=20)
            with pytest.raises(ValidationError, match="not sliced") as err:
                client.submit(s.JobSubmit(model=gcode, filename="cura.gcode",
                                          overrides={"filament_diameter_mm": "2.85"}))
            assert err.value.details["field"] == "overrides"
            assumed = client.submit(s.JobSubmit(model=gcode, filename="cura.gcode")).job_id
            told = client.submit(s.JobSubmit(model=gcode, filename="cura.gcode", filament_diameter_mm=2.85)).job_id
            a = wait_job(client, assumed, lambda r: r.plan is not None)
            b = wait_job(client, told, lambda r: r.plan is not None)
            assert (a.plan.filament_diameter_mm, a.plan.material_source) == (1.75, "assumed")
            assert (b.plan.filament_diameter_mm, b.plan.material_source) == (2.85, "option")
            assert b.filament_diameter_mm == 2.85
            assert b.plan.extruded_mm3 == pytest.approx(a.plan.extruded_mm3 * (2.85 / 1.75) ** 2, rel=1e-6)
            # the console shows whole ids; fabric-cli job show also takes a unique start of one
            args = replace(settings, mode="client").to_args()
            assert main(["job", "show", told[:6], *args]) == 0
            assert f"job {told}" in capsys.readouterr().out
            assert main(["job", "show", "zz", *args]) != 0
            assert "no job id starts with 'zz'" in capsys.readouterr().err
    finally:
        for svc in reversed(services):
            svc.close()
