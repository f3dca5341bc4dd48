"""Work-object calibration: planted plate errors recovered by simulated probing."""
from __future__ import annotations

import numpy as np
import pytest

from fabric.motion.testprog import square_program
from fabric.robot.cell import Cell
from fabric.robot.frames import inv_T, xyzrpy_to_T
from fabric.sim.calibration import calibrate_plate
from fabric.sim.twin import Twin
from fabric.wire.errors import ConfigError, StateError, ValidationError

LO, HI = np.array([0.0, 0.0, -10.0]), np.array([250.0, 250.0, 0.0])


def pose_error(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    """Translation (mm) and rotation angle (deg) between two frames."""
    D = inv_T(A) @ B
    R = D[:3, :3]
    axis_sin = 0.5 * np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    ang = np.degrees(np.arctan2(axis_sin, (np.trace(R) - 1) / 2))
    return float(np.linalg.norm(D[:3, 3])), float(ang)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fit_recovers_planted_error(seed: int) -> None:
    nominal = xyzrpy_to_T([475.0, -125.0, 10.0], [0, 0, 0])
    planted = xyzrpy_to_T([2.5, -3.0, 1.7], [0.3, -0.2, 0.4])
    true = nominal @ planted
    res, _plan, frames = calibrate_plate(nominal, true, LO, HI, 0.01, np.random.default_rng(seed))
    dp, ang = pose_error(true, res.work_object_T)
    assert dp < 0.05 and ang < 0.01
    np.testing.assert_allclose(res.correction_xyz_mm, [2.5, -3.0, 1.7], atol=0.05)
    np.testing.assert_allclose(res.correction_rpy_deg, [0.3, -0.2, 0.4], atol=0.01)
    assert 0.003 < res.residual_rms_mm < 0.03                  # consistent with 0.01 mm noise per axis
    assert frames.shape == (res.n_points, 4, 4) and res.n_points == 16 + 12
    before, _ = pose_error(true, nominal)
    assert before > 4.0                                         # the error was real


def test_noise_free_fit_is_exact_and_gross_error_misses() -> None:
    nominal = xyzrpy_to_T([475.0, -125.0, 10.0], [0, 0, 0])
    true = nominal @ xyzrpy_to_T([1.0, 2.0, -0.5], [-0.1, 0.05, -0.3])
    res, _, _ = calibrate_plate(nominal, true, LO, HI, 0.0, np.random.default_rng(0))
    dp, ang = pose_error(true, res.work_object_T)
    assert dp < 1e-9 and ang < 1e-8 and res.residual_rms_mm < 1e-9
    shifted = nominal @ xyzrpy_to_T([-40.0, 0, 0], [0, 0, 0])  # side probes would start inside the plate
    with pytest.raises(ConfigError) as e:
        calibrate_plate(nominal, shifted, LO, HI, 0.01, np.random.default_rng(0))
    assert e.value.details["field"] == "probe"


def test_twin_calibrate_updates_work_object() -> None:
    cell = Cell.builtin("irb140")
    cell.true_plate_T = cell.plate_T @ xyzrpy_to_T([3.0, -2.0, 1.5], [0.25, -0.2, 0.5])
    twin = Twin(cell)
    twin.load(square_program(cell))
    res = twin.calibrate()
    dp, ang = pose_error(cell.true_wobj_T(), twin.work_object_T)
    assert dp < 0.05 and ang < 0.01
    assert twin.state == "idle" and "re-plan" in twin.reason  # the old program was for the old frame
    with pytest.raises(ValidationError) as e:
        twin.load(square_program(Cell.builtin("irb140")))       # planned on the nominal plate
    assert e.value.details["field"] == "wobj"
    np.testing.assert_allclose(res.work_object_T, twin.work_object_T)
    twin.load(_replanned(twin))
    assert twin.state == "ready"
    twin.start()
    with pytest.raises(StateError):
        twin.calibrate()


def _replanned(twin: Twin):
    """The square re-planned for the calibrated work object (what the planner does after calibration)."""
    cal = Cell.builtin("irb140")
    cal.plate_T = twin.work_object_T @ inv_T(cal.wobj_T()) @ cal.plate_T
    return square_program(cal)
