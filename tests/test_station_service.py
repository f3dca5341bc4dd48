"""The station service over real in-process Zenoh sessions: the paper's commands end to end."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.motion.testprog import square_program
from fabric.programs import program_artifact
from fabric.robot.cell import Cell
from fabric.services.collision import CollisionService
from fabric.services.planner import PlannerService
from fabric.services.station import StationService
from fabric.wire.errors import NotFound, StateError, ValidationError

pytestmark = pytest.mark.timeout(180)


@pytest.fixture(scope="module")
def cell():
    return Cell.builtin("irb140")


@pytest.fixture
def fabric(session, settings, cell):
    """Station, collision and planner services in this process, plus a client.

    Yields (client, station, program id, planner); the program heats the nozzle to 200 C first."""
    planner = PlannerService(session, settings.cell, cell)
    collision = CollisionService(session, settings.cell, cell)
    station = StationService(session, settings.cell, cell, pose_hz=100.0)
    program = square_program(cell, size_mm=20, layers=3, layer_height_mm=0.5, speed_mm_s=40, nozzle_c=200.0)
    pid = planner.store_artifact(program_artifact(program))
    for svc in (planner, collision, station):
        svc.start()
    with Client.connect(settings) as client:
        client.wait_alive(("station", "collision", "planner"), deadline_s=20)
        yield client, station, pid, planner
    for svc in (station, collision, planner):
        svc.close()


def wait_event(sub, kinds: tuple[str, ...], timeout: float = 60.0) -> s.Event:
    while True:
        ev = sub.get(timeout=timeout)
        if ev.kind in kinds:
            return ev


def test_position_and_time_before_load(fabric, cell):
    client, _, _, _ = fabric
    pose = client.position()
    assert np.allclose(np.radians(pose.q_deg), cell.home_q_rad, atol=1e-9)
    assert len(pose.xyz_mm) == 3 and len(pose.quat_wxyz) == 4
    with pytest.raises(StateError):
        client.pause()
    with pytest.raises(StateError):
        client.collisions()


def test_load_unknown_program_is_not_found(fabric):
    client, _, _, _ = fabric
    with pytest.raises(NotFound):
        client.load("0" * 64)


def test_print_at_max_speed_estimate_matches_and_events_are_lossless(fabric):
    client, _station, pid, _ = fabric
    info = client.load(pid)
    assert info.estimate_s > 0 and info.total_s == pytest.approx(info.estimate_s)
    report = client.collisions()
    assert report.collision_free and report.checked_configs > 0
    events = client.subscribe("station", "events")
    try:
        client.start(rtf=0)
        end = wait_event(events, ("finished", "fault"))
    finally:
        events.close()
    assert end.kind == "finished"
    done = client.time()
    assert done.total_s == pytest.approx(info.estimate_s, rel=1e-9)
    assert done.remaining_s == pytest.approx(0.0, abs=1e-9)
    history = client.events(0).events
    seqs = [e.seq for e in history]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))          # gap-free
    kinds = [e.kind for e in history]
    assert kinds.count("layer") >= 3 and kinds[0] == "started" and kinds[-1] == "finished"
    assert "extruder_on" not in kinds and len(kinds) < 20           # what an operator reads, not one per bead
    import io

    import trimesh
    mesh = trimesh.load(io.BytesIO(client.mesh("stl").data), file_type="stl")
    assert len(mesh.faces) > 0 and mesh.extents[0] == pytest.approx(20.0, abs=2.0)


def test_pause_resume_and_stop_over_the_fabric(fabric):
    client, _station, pid, _ = fabric
    client.load(pid)
    events = client.subscribe("station", "events")
    try:
        client.start(rtf=30.0)                      # heat up quickly ...
        wait_event(events, ("layer",))
        client.set_rtf(1.0)                         # ... then print in real time: seconds to pause mid-layer
        ack = client.pause()
        assert ack.state == "paused"
        paused = wait_event(events, ("paused",))    # once the controlled stop, retract and lift are done
        lifted = client.position()
        with pytest.raises(StateError):
            client.start()
        client.resume(rtf=0)
        assert wait_event(events, ("resumed", "fault")).kind == "resumed"
        end = wait_event(events, ("finished", "fault"))
    finally:
        events.close()
    assert end.kind == "finished"
    assert lifted.xyz_mm[2] == pytest.approx(paused.data["xyz_mm"][2] + 5.0, abs=1e-6)   # lifted clear by 5 mm
    st = client.state()
    assert st.state == "idle" and st.reason == "finished"


def test_overrides_calibrate_ready_and_home(fabric, cell):
    client, _station, pid, _ = fabric
    st = client.overrides(speed_r=1.5, flow_r=0.9, nozzle_c=210.0)
    assert st.speed_r == pytest.approx(1.5) and st.flow_r == pytest.approx(0.9)
    temps = client.subscribe("station", "temps")
    try:
        t = temps.get(timeout=10)
        assert t.nozzle_target_c == pytest.approx(210.0)
    finally:
        temps.close()
    client.load(pid)
    ready = client.ready()
    names = {c.name: c for c in ready.checks}
    assert names["program planned and loaded"].ok
    assert names["program collision-free"].ok, ready.checks
    assert not names["services alive"].ok            # slicer and supervisor are not running here
    assert not ready.ready
    events = client.subscribe("station", "events")
    try:
        ack = client.home()
        assert "home" in ack.message
        wait_event(events, ("home",))
    finally:
        events.close()
    assert np.allclose(np.radians(client.position().q_deg), cell.home_q_rad, atol=1e-6)
    cal = client.calibrate()
    assert cal.points >= 6 and cal.residual_rms_mm < 0.1
    assert client.state().wobj_xyz_mm == pytest.approx(cal.wobj_xyz_mm)
    with pytest.raises(ValidationError) as e:        # planned for the old work object: re-plan
        client.load(pid)
    assert e.value.details.get("field") == "wobj"


def test_pose_stream_rate_and_content(fabric):
    client, _, _, _ = fabric
    sub = client.subscribe("station", "pose")
    try:
        msgs = [sub.get(timeout=5) for _ in range(20)]
    finally:
        sub.close()
    seqs = [m.seq for m in msgs]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    walls = [m.wall_time_s for m in msgs]
    assert walls == sorted(walls)


def test_real_time_then_max_speed_gives_the_same_print_as_max_speed(fabric):
    """Simulated time is exact: running part of the print at rtf 1 changes nothing but the wall time."""
    client, _, _, planner = fabric
    cold = square_program(Cell.builtin("irb140"), size_mm=20, layers=3, speed_mm_s=40)   # no heat-up wait
    pid = planner.store_artifact(program_artifact(cold))
    ends = []
    for plan in (("max",), ("rt", "max")):
        client.clear_plate()                    # the first print's part is taken off
        client.load(pid)
        events = client.subscribe("station", "events")
        try:
            client.start(rtf=1.0 if plan[0] == "rt" else 0.0)
            if plan[0] == "rt":
                first = wait_event(events, ("layer",))                  # really running at rtf 1
                assert client.state().rtf == 1.0 and first.t_sim_s > 0
                client.set_rtf(0.0)
            ends.append(wait_event(events, ("finished", "fault")))
        finally:
            events.close()
    a, b = ends
    assert a.kind == b.kind == "finished"
    assert b.data["elapsed_s"] == pytest.approx(a.data["elapsed_s"], rel=1e-9)
    assert b.data["extruded_mm3"] == pytest.approx(a.data["extruded_mm3"], rel=1e-9)
    assert b.data["beads"] == a.data["beads"]


def test_a_simulation_failure_faults_the_job_and_the_station_keeps_serving(fabric, monkeypatch):
    client, station, pid, _ = fabric
    client.load(pid)
    twin = station.commands.read(lambda: station.twin)       # the clock's own: used by the clock below
    real_advance = twin.advance
    calls = {"n": 0}

    def broken(dt_s):                          # the clock ticks in every state: fail once, mid-print
        if twin.state == "printing" and calls["n"] == 0:
            calls["n"] += 1
            raise RuntimeError("planted")
        return real_advance(dt_s)

    events = client.subscribe("station", "events")
    try:
        monkeypatch.setattr(twin, "advance", broken)
        client.start(rtf=0)
        ev = wait_event(events, ("fault", "finished"))
    finally:
        events.close()
    assert ev.kind == "fault" and "planted" in client.state().reason
    assert station.degraded and "planted" in station.degraded
    assert len(client.position().q_deg) == 6                  # still serving


def _stopped_in_the_first_layer(client, events) -> None:
    """Print until the first layer has beads, then stop: the part's top is layer 1."""
    client.start(rtf=30.0)                      # heating, fast
    wait_event(events, ("layer",))
    extrusion = client.subscribe("station", "extrusion")
    try:
        client.set_rtf(0.5)                     # the first beads, slowly
        while extrusion.get(timeout=30.0).extruded_mm3 <= 0.0:     # the telemetry says a bead is laid
            pass
    finally:
        extrusion.close()
    client.stop()
    wait_event(events, ("stopped",))


def test_going_on_above_the_part_and_the_next_layer_is_refused(fabric):
    """Stopped in layer 1, ``start --layer 3`` would lay layer 3 on nothing (a typo, and the print goes on in
    the air): refused, naming the part's top, and nothing changes; layer 2 (and layer 1, where it ends) go on.
    A recovery at a layer is held to the same rule."""
    client, station, pid, _ = fabric
    client.load(pid)
    events = client.subscribe("station", "events")
    try:
        _stopped_in_the_first_layer(client, events)
        with pytest.raises(StateError, match=r"go on at a layer of it \(start --layer 1: it goes on where the part "
                                             r"ends, in layer 1\)"):
            client.start(rtf=0)                              # not again from the beginning: which layer, said
        before, seq = client.state(), client.events(0).last_seq
        with pytest.raises(StateError, match=r"printed up to layer 1, so layer 3 would be laid 1 layer\(s\) above "
                                             r"it, in the air; go on at layer 1 \(where it ends\) or 2") as err:
            client.start(rtf=0, from_layer=2)
        assert err.value.details["top_layer"] == 1 and err.value.details["from_layer"] == 3
        after = client.state()
        assert (after.state, after.deposited_mm3, client.events(0).last_seq) == ("stopped", before.deposited_mm3,
                                                                                  seq)
        with pytest.raises(ValidationError, match="no layer 7"):            # a layer the program has not
            client.start(from_layer=6)
        assert station.commands.read(station.plate.top_layer) == 0
        assert "from layer 2" in client.start(rtf=0.5, from_layer=1).message
        wait_event(events, ("at_layer", "fault"))
        station.commands.change(lambda: station.twin.interrupt("killed by the test"))   # it dies in layer 2
        assert client.state().state == "interrupted"
        assert station.commands.read(station.plate.top_layer) == 0      # arrived at layer 2, no bead of it yet
        with pytest.raises(StateError, match=r"cannot recover at layer 3: .* in the air"):
            client.recover(rtf=0, from_layer=2)
        assert client.state().state == "interrupted"
    finally:
        events.close()


def test_stop_then_start_again_at_a_layer(fabric):
    client, station, pid, _ = fabric
    client.load(pid)
    events = client.subscribe("station", "events")
    try:
        client.start(rtf=30.0)
        while wait_event(events, ("layer",)).layer < 1:
            pass
        client.stop()
        wait_event(events, ("stopped",))
        with pytest.raises(ValidationError, match="no layer 7"):
            client.start(from_layer=6)
        assert client.state().state == "stopped"
        top = station.commands.read(station.plate.top_layer)         # layer 1, or 2 if a bead of it was laid
        ack = client.start(rtf=0, from_layer=top + 1)                 # the next layer
        assert f"from layer {top + 2}" in ack.message
        assert wait_event(events, ("at_layer", "fault")).kind == "at_layer"
        assert wait_event(events, ("finished", "fault")).kind == "finished"
    finally:
        events.close()
    csv = client.mesh("csv").data.decode().splitlines()
    assert len(csv) > 4 + 1                          # the first layers, a partial one, then layer 3


def test_one_clock_and_honest_progress(fabric):
    client, _station, pid, _ = fabric
    client.load(pid)
    st0 = client.state()
    assert st0.progress_r == 0.0 and st0.planned_mm3 > 0
    events = client.subscribe("station", "events")
    try:
        client.start(rtf=30.0)
        while wait_event(events, ("layer",)).layer < 1:
            pass
        client.pause()                  # at rtf 30, so that layer 1 is still the one paused in on a busy host
        wait_event(events, ("paused",))
        client.set_rtf(100.0)
        a = client.state()
        pose = client.position()
        a_after = client.state()
        wait_for = a.t_sim_s + 3.0
        while client.state().t_sim_s < wait_for:                # simulated time goes on while paused
            pass
        b = client.state()
        assert 0.0 < a.progress_r < 1.0 and b.progress_r == a.progress_r       # frozen while paused
        assert b.deposited_mm3 == a.deposited_mm3 and b.elapsed_s > a.elapsed_s
        # one clock for state and pose: the position read between two states lies between them (less one tick
        # of the clock, 20 ms of wall time at rtf 100, as the position is the last tick's)
        assert a.t_sim_s - 0.02 * 100 <= pose.t_sim_s <= a_after.t_sim_s
        assert a.layer == 1 and a.layers_total == 3
        client.stop()
        wait_event(events, ("stopped",))
        c = client.state()
        assert c.state == "stopped" and c.progress_r == pytest.approx(a.progress_r, abs=0.02) and c.progress_r < 1
    finally:
        events.close()


def test_events_by_kind_and_overrides_on_record(fabric):
    client, _station, pid, _ = fabric
    client.load(pid)
    client.overrides(speed_r=1.2)
    events = client.subscribe("station", "events")
    try:
        client.start(rtf=0)
        wait_event(events, ("finished",))
    finally:
        events.close()
    layers = client.events(0, kinds=["layer"]).events
    assert [e.layer for e in layers] == [0, 1, 2] and all(e.kind == "layer" for e in layers)
    override = client.events(0, kinds=["override"]).events
    assert override and override[-1].data == {"speed_r": 1.2}
    with pytest.raises(ValidationError, match="unknown event kinds"):
        client.events(0, kinds=["extruder_on"])


def test_extrusion_and_temps_are_published_on_change_pose_at_its_rate(fabric):
    """The pose stream runs at the pose rate; extrusion comes at every switch of the extruder (and flow or
    layer change) plus 20 Hz, in its own gap-free sequence; temperatures on a new set point plus 10 Hz."""
    import time
    client, _, pid, _ = fabric
    pose, ext, temps = (client.subscribe("station", t) for t in ("pose", "extrusion", "temps"))
    events = client.subscribe("station", "events")
    try:
        client.load(pid)
        client.start(rtf=20.0)
        t0 = time.monotonic()
        end = wait_event(events, ("finished",), timeout=120)
        wall_s = time.monotonic() - t0
        # the streams of the finishing tick follow its event: take them up to a sample at or after it
        poses, exts, ts = _until(pose, end.t_sim_s), _until(ext, end.t_sim_s), _drain(temps)
    finally:
        for sub in (pose, ext, temps, events):
            sub.close()
    assert len(poses) > 0.8 * 100.0 * wall_s                      # 100 Hz
    assert len(exts) < 0.6 * len(poses) and len(ts) < 0.3 * len(poses)
    assert [e.seq for e in exts] == list(range(exts[0].seq, exts[0].seq + len(exts)))
    switches = sum(a.on != b.on for a, b in itertools.pairwise(exts))
    assert switches >= 2 and any(e.on for e in exts)               # the extruder went on and off: both seen
    assert exts[-1].extruded_mm3 > 0 and not exts[-1].on
    assert any(t.nozzle_target_c == 200.0 for t in ts)


def _until(sub, t_sim_s: float, timeout_s: float = 10.0) -> list:
    """Messages of ``sub`` up to the first one at or after ``t_sim_s`` (each waited for at most ``timeout_s``)."""
    out = [sub.get(timeout=timeout_s)]
    while out[-1].t_sim_s < t_sim_s:
        out.append(sub.get(timeout=timeout_s))
    return out


def _drain(sub) -> list:
    import queue
    out = []
    while True:
        try:
            out.append(sub.get(timeout=0.0))
        except queue.Empty:
            return out
