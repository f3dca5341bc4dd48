"""The robot link's decisions and figures as pure logic (the fast tier): the timed reference, the deviation
across the commanded path and its run figures, and what a tick tells the station (pause a bead laid off its
path, stop an arm that runs away, interrupt on a fault), with a controller that reports given steps."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import fabric
from fabric.drivers.address import ENV_VAR, parse_robot, robot_address
from fabric.drivers.controller import ControllerInfo, ControllerStatus, Tracking
from fabric.drivers.deviation import DeviationStats, path_deviation_mm
from fabric.drivers.reference import Reference
from fabric.robot.cell import Cell
from fabric.schemas.states import Station
from fabric.services.station_robot import STATUS_EVERY, RobotLink
from fabric.sim.twin import Twin
from fabric.wire.errors import ConfigError, RobotError


def test_the_reference_interpolates_holds_when_dry_and_replaces_what_was_ahead():
    ref = Reference(2)
    with pytest.raises(LookupError):
        ref.at(0.0)
    ref.put(np.array([0.0, 1.0, 2.0]), np.array([[0.0, 0.0], [1.0, 2.0], [2.0, 2.0]]))
    q, dq, dry = ref.at(0.5)
    assert np.allclose(q, [0.5, 1.0]) and np.allclose(dq, [1.0, 2.0]) and not dry
    q, dq, dry = ref.at(3.0)
    assert np.allclose(q, [2.0, 2.0]) and np.allclose(dq, 0.0) and dry
    ref.put(np.array([1.5, 2.5]), np.array([[5.0, 5.0], [6.0, 6.0]]))       # a pause: the future replaced
    assert np.allclose(ref.at(1.25)[0], [3.0, 3.5])                         # between the kept 1.0 and the new 1.5
    assert np.allclose(ref.at(2.5)[0], [6.0, 6.0])
    assert len(ref.between(0.2, 1.6)) == 4                                   # both ends, the samples at 1.0 and 1.5
    with pytest.raises(ValueError):
        ref.put(np.array([3.0, 3.0]), np.zeros((2, 2)))


def test_the_deviation_is_across_the_path_not_along_it():
    path = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [10.0, 10.0, 0.0]])
    p = np.array([[5.0, 0.3, 0.0], [10.2, 5.0, 0.0], [3.0, 0.0, 0.4], [-1.0, 0.0, 0.0]])
    assert np.allclose(path_deviation_mm(p, path), [0.3, 0.2, 0.4, 1.0])
    assert np.allclose(path_deviation_mm(p[:1], path[:1]), [np.hypot(5.0, 0.3)])


def test_a_runs_figures_are_its_quantiles_and_where_its_worst_step_was():
    stats = DeviationStats()
    stats.add(np.full(98, 0.1), 1.0, 10, 100)
    stats.add(np.array([0.4, 2.0]), 2.0, 20, 200)
    out = stats.summary()
    assert out["p50_mm"] == pytest.approx(0.1, abs=0.001) and out["p99_mm"] == pytest.approx(0.4, abs=0.001)
    assert (out["max_mm"], out["steps"], out["max_row"], out["max_gcode_line"]) == (2.0, 100, 20, 200)


class StepsController:
    """A controller that reports the steps it is given (the link's logic only)."""

    address = "franka:stub"

    def __init__(self, q_rad: np.ndarray) -> None:
        self.q = q_rad
        self.steps = Tracking.empty(len(q_rad))
        self.fault = ""
        self.stopped = 0

    def connect(self) -> ControllerInfo:
        return ControllerInfo(self.address, "franka", 10, len(self.q), self.q.copy())

    recover = connect

    def status(self) -> ControllerStatus:
        return ControllerStatus(self.address, connected=True, following=True, server_version=10, fault=self.fault,
                                q_rad=self.q.copy())

    def follow(self, reference: Reference) -> None:
        self.reference = reference

    def tracking(self) -> Tracking:
        out, self.steps = self.steps, Tracking.empty(len(self.q))
        return out

    def stop(self) -> None:
        self.stopped += 1

    def close(self) -> None:
        pass


@pytest.fixture()
def link():
    cell = Cell.builtin("fr3")
    twin = Twin(cell)
    ctl = StepsController(np.asarray(cell.home_q_rad, dtype=float))
    lk = RobotLink(ctl, twin, bound_mm=0.5)
    lk.connect(twin)
    return lk, twin, ctl


def _steps_off(twin: Twin, ctl: StepsController, off_mm: float, now: float) -> None:
    """Ten steps whose measured joints put the nozzle ``off_mm`` beside where it is commanded (+z of the base)."""
    q = np.asarray(twin.pose().q_rad)
    T = np.asarray(twin.robot.fk(q[None]))[0]
    T[2, 3] += off_mm
    q_off, status = twin.robot.ik(T[None], q)
    assert status[0] == 0
    ctl.steps = Tracking(now - 0.02 + 0.002 * np.arange(10), np.tile(q, (10, 1)), np.tile(q_off[0], (10, 1)))


def test_a_bead_laid_off_its_path_pauses_the_print_and_a_travel_does_not(link):
    lk, twin, ctl = link
    twin.s.state = Station.PRINTING
    _steps_off(twin, ctl, 0.8, 100.0)
    assert lk.tick(twin, 100.0, 7, 321, extruding=False) is None          # travelling: not a bead
    _steps_off(twin, ctl, 0.8, 100.02)
    action = lk.tick(twin, 100.02, 7, 321, extruding=True)
    assert action is not None and action.kind == "pause"
    assert "0.80 mm" in action.reason and "bound 0.5 mm" in action.reason and "line 321" in action.reason
    _steps_off(twin, ctl, 0.3, 100.04)
    assert lk.tick(twin, 100.04, 7, 322, extruding=True) is None


def test_an_arm_that_runs_away_is_stopped_and_a_fault_interrupts(link):
    lk, twin, ctl = link
    _steps_off(twin, ctl, 12.0, 100.0)
    action = lk.tick(twin, 100.0, -1, -1, extruding=False)                   # at rest, idle: still stopped
    assert action is not None and action.kind == "interrupt" and "12.0 mm off" in action.reason
    twin.s.state = Station.PRINTING
    ctl.fault = "the robot stopped in error: joint_reflex"
    actions = [lk.tick(twin, 100.02 + 0.02 * k, -1, -1, extruding=True) for k in range(STATUS_EVERY)]
    action = next(a for a in actions if a is not None)                       # read within STATUS_EVERY ticks
    assert action is not None and action.kind == "interrupt" and "joint_reflex" in action.reason


def test_a_motion_is_refused_while_the_robot_is_not_ready(link):
    lk, _twin, ctl = link
    lk.gate("home")                                                           # ready: nothing said
    ctl.fault = "the connection to the robot was lost"
    with pytest.raises(RobotError, match="home refused: robot franka:stub: the connection to the robot was lost"):
        lk.gate("home")


@pytest.mark.parametrize("text, why", [
    ("franka", "KIND:HOST"), ("franka:", "KIND:HOST"), ("franka: 10.0.0.2 x", "KIND:HOST"),
    ("ur:10.0.0.2", "unknown robot kind 'ur'"),
])
def test_a_robot_address_that_is_none_is_a_typed_error_naming_where(text, why):
    with pytest.raises(ConfigError, match=why) as err:
        parse_robot(text, "--robot")
    assert err.value.details["field"] == "--robot" and err.value.details["value"] == text


def test_the_robot_comes_from_the_option_then_the_cell_file_then_the_environment(monkeypatch):
    monkeypatch.setenv(ENV_VAR, "franka:10.0.0.3")
    assert str(robot_address("franka:10.0.0.1", "franka:10.0.0.2")) == "franka:10.0.0.1"
    assert str(robot_address(None, "franka:10.0.0.2")) == "franka:10.0.0.2"
    assert str(robot_address(None, "")) == "franka:10.0.0.3"
    assert robot_address("twin", "franka:10.0.0.2") is None                 # the twin alone, said on the line
    monkeypatch.setenv(ENV_VAR, "franka")
    with pytest.raises(ConfigError, match=ENV_VAR):
        robot_address(None, "")


def test_a_cell_files_robot_keys_are_checked_when_it_is_read():
    text = (Path(fabric.__file__).parent / "cells" / "fr3.toml").read_text()
    for key, value, why in (("controller", '"franka"', "robot.controller"),
                            ("deviation_bound_mm", "0", "deviation_bound_mm")):
        bad = text.replace('brand = "franka"', f'brand = "franka"\n{key} = {value}', 1)
        with pytest.raises(ConfigError, match=why):
            Cell.from_toml_text(bad, source="bad.toml")
    good = text.replace('brand = "franka"', 'brand = "franka"\ncontroller = "franka:10.0.0.2"\n'
                                            'deviation_bound_mm = 1.5', 1)
    cell = Cell.from_toml_text(good, source="good.toml")
    assert (cell.controller, cell.deviation_bound_mm) == ("franka:10.0.0.2", 1.5)
    assert cell.fingerprint() == Cell.builtin("fr3").fingerprint()           # where the robot is: not the cell


def test_up_with_a_bad_robot_says_so_in_one_line_and_starts_nothing(capsys):
    from fabric.cli.main import main
    assert main(["up", "--robot", "franka", "--cell-config", "fr3"]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--robot" in err and "KIND:HOST" in err, err
