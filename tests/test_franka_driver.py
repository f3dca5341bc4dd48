"""The Franka driver against franky-sim as a process: connecting, following a timed reference, stopping,
and each way a connection fails (a wrong host, a robot held by another client, another server version, the
robot gone while driven): one typed RobotError each, within the driver's deadline."""
from __future__ import annotations

import os
import time

import numpy as np
import pytest

from fabric.drivers.reference import Reference
from fabric.robot.cell import Cell
from fabric.wire.errors import RobotError

from support.franky_sim import FrankySim, favour, free_loopback, need_franky

pytestmark = [pytest.mark.slow, pytest.mark.alone]     # franky-sim's 1 kHz loop needs the cores (conftest)


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    need_franky()
    favour(os.getpid())                   # this process drives the arm: its streaming thread keeps its period
    with FrankySim(tmp_path_factory.mktemp("sim") / "franky-sim.log") as running:
        yield running


@pytest.fixture(scope="module")
def fr3():
    return Cell.builtin("fr3")


def _controller(host: str, **kw):
    from fabric.drivers.franka import FrankaController
    return FrankaController(host, **kw)


def _line(cell: Cell, q_start: np.ndarray, length_mm: float, speed_mm_s: float, dt_s: float = 0.004):
    """Joints along a straight line of the nozzle (+x of the base, from where it stands), timed at a speed
    with a ramp of 0.2 s at each end (the speed rises and falls linearly)."""
    r = cell.robot
    T0 = np.asarray(r.fk(q_start[None]))[0]
    ramp_s, cruise_s = 0.2, length_mm / speed_mm_s
    t = np.arange(0.0, cruise_s + 2 * ramp_s, dt_s)
    v = np.interp(t, [0, ramp_s, cruise_s, cruise_s + ramp_s], [0, speed_mm_s, speed_mm_s, 0])
    s = np.concatenate([[0.0], np.cumsum((v[1:] + v[:-1]) / 2 * dt_s)])
    T = np.repeat(T0[None], len(t), axis=0)
    T[:, 0, 3] += s
    q, status = r.ik(T, q_start)
    assert (status == 0).all()
    return t, q


def _go_home(ctl, ref: Reference, cell: Cell, q_from: np.ndarray, duration_s: float = 4.0) -> np.ndarray:
    """A smooth joint move (cosine blend) from where the robot stands to the cell's home, followed to rest. Slow:
    a 2 s move ran away in one of several runs (the station times its own joint moves for the arm: station_robot)."""
    t = np.arange(0.0, duration_s, 0.004)
    w = (1 - np.cos(np.pi * t / duration_s)) / 2
    q = q_from + w[:, None] * (np.asarray(cell.home_q_rad) - q_from)
    ref.put(time.monotonic() + 0.05 + t, q)
    time.sleep(duration_s + 0.5)                   # the move's own duration on the arm, then it settles
    ctl.tracking()
    return q[-1]


def _following_at_home(host: str, cell: Cell):
    """A connected controller following a reference, the arm brought home: (controller, reference, home)."""
    ctl = _controller(host)
    info = ctl.connect()
    ref = Reference(7)
    ref.hold(info.q_rad, time.monotonic())
    ctl.follow(ref)
    return ctl, ref, _go_home(ctl, ref, cell, info.q_rad)


def test_connect_reports_the_robot_and_its_server_version(sim):
    ctl = _controller(sim.host)
    try:
        info = ctl.connect()
        assert (info.address, info.kind, info.server_version, info.dof) == (f"franka:{sim.host}", "franka", 10, 7)
        st = ctl.status()
        assert st.connected and st.ok and not st.following and st.errors == []
        assert np.allclose(st.q_rad, info.q_rad, atol=1e-3)
    finally:
        ctl.close()


def test_it_follows_a_timed_line_and_stops_where_told(sim, fr3):
    ctl, ref, home = _following_at_home(sim.host, fr3)
    try:
        t, q = _line(fr3, home, 40.0, 20.0)
        t0 = time.monotonic() + 0.05
        ref.put(t0 + t, q)
        time.sleep(t[-1] + 0.6)                    # the line takes its time on the arm (real time), then settles
        tr = ctl.tracking()
        assert len(tr) > 0.6 * (t[-1] / 0.002)            # the stream ran at its period, give or take a loaded host
        r = fr3.robot
        dev = np.linalg.norm(r.tcp_xyz_mm(tr.q_meas_rad) - r.tcp_xyz_mm(tr.q_cmd_rad), axis=1)
        end = np.linalg.norm(r.tcp_xyz_mm(tr.q_meas_rad[-1:]) - r.tcp_xyz_mm(q[-1:]))
        assert end < 0.5, f"settled {end:.3f} mm from the line's end"
        assert np.percentile(dev, 50) < 0.3 and dev.max() < 1.5, (np.percentile(dev, [50, 99]), dev.max())
        ctl.stop()
        assert not ctl.status().following
        a = np.asarray(ctl.status().q_rad)
        time.sleep(0.3)
        assert np.abs(np.asarray(ctl.status().q_rad) - a).max() < 2e-3        # at rest once stopped
    finally:
        ctl.close()


def test_a_dry_reference_holds_the_robot_at_its_last_sample(sim, fr3):
    ctl, ref, home = _following_at_home(sim.host, fr3)
    try:
        t, q = _line(fr3, home, 60.0, 30.0)
        half = len(t) // 2
        ref.put(time.monotonic() + 0.05 + t[:half], q[:half])      # the station stops feeding halfway
        time.sleep(t[-1] + 0.5)                    # as long as the whole line would have taken
        meas = fr3.robot.tcp_xyz_mm(np.asarray(ctl.status().q_rad)[None])[0]
        assert np.linalg.norm(meas - fr3.robot.tcp_xyz_mm(q[half - 1:half])[0]) < 0.5
    finally:
        ctl.close()


def test_a_host_with_no_controller_is_one_typed_line():
    need_franky()
    host = free_loopback()                          # nothing listens there
    t0 = time.monotonic()
    with pytest.raises(RobotError) as err:
        _controller(host).connect()
    assert time.monotonic() - t0 < 3.0
    assert err.value.details["reason"] == "unreachable" and "nothing listens" in err.value.message
    assert "\n" not in err.value.message


def test_a_robot_held_by_another_client_is_busy(sim):
    first = _controller(sim.host)
    first.connect()
    try:
        t0 = time.monotonic()
        with pytest.raises(RobotError) as err:
            _controller(sim.host, connect_timeout_s=2.0).connect()
        assert time.monotonic() - t0 < 5.0
        assert err.value.details["reason"] == "busy" and "another client" in err.value.message
    finally:
        first.close()


def test_another_server_version_is_refused_naming_both(tmp_path):
    need_franky()
    with FrankySim(tmp_path / "sim9.log", server_version=9) as old:
        with pytest.raises(RobotError) as err:
            _controller(old.host).connect()
    d = err.value.details
    assert d["reason"] == "version" and d["library_version"] == 10, err.value.message
    assert d["server_version"] == 9 and "9" in err.value.message and "10" in err.value.message


def test_the_robot_gone_while_driven_is_a_fault_within_a_second(tmp_path):
    need_franky()
    sim = FrankySim(tmp_path / "gone.log").start()
    ctl = _controller(sim.host)
    try:
        info = ctl.connect()
        ref = Reference(7)
        ref.hold(info.q_rad, time.monotonic())
        ctl.follow(ref)
        time.sleep(0.3)
        sim.kill()
        t0 = time.monotonic()
        while time.monotonic() - t0 < 3.0 and ctl.status().ok:
            time.sleep(0.02)
        st = ctl.status()
        assert not st.ok and st.fault, st
        assert time.monotonic() - t0 < 1.0, f"noticed after {time.monotonic() - t0:.2f} s: {st.fault}"
    finally:
        ctl.close()
        sim.kill()
