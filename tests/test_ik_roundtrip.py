"""FK -> IK -> FK round trips of every built-in 6-axis cell's closed form, 10,000 random configurations each."""
from __future__ import annotations

import numpy as np
import pytest

from fabric.robot.cell import Cell
from fabric.robot.closed_form import ClosedFormIK
from fabric.robot.kinematics import IK_OK, IK_SINGULAR

from support.ik_checks import assert_tracking_equals_full_rule

ROBOTS = ["irb140", "kr6r700", "ur5", "ur10"]
FAMILY = {"irb140": "opw", "kr6r700": "opw", "ur5": "ur", "ur10": "ur"}
N = 10_000


def rotation_error_rad(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle (N,) of ``Ra^T Rb``, accurate for small angles: ``|Ra - Rb|_F = 2 sqrt(2) sin(angle / 2)``."""
    f = np.sqrt(np.sum((Ra - Rb) ** 2, axis=(1, 2)))
    return 2.0 * np.arcsin(np.minimum(1.0, f / (2.0 * np.sqrt(2.0))))


@pytest.fixture(scope="module", params=ROBOTS)
def cell(request: pytest.FixtureRequest) -> Cell:
    return Cell.builtin(request.param)


def _random_q(cell: Cell, seed: int) -> np.ndarray:
    r = cell.robot
    rng = np.random.default_rng(seed)
    return rng.uniform(r.lower_rad, r.upper_rad, (N, 6))


def test_family_is_detected(cell: Cell) -> None:
    assert cell.robot.ik_family == FAMILY[cell.name]
    assert isinstance(cell.robot.solver, ClosedFormIK) and cell.robot.closed_form is cell.robot.solver


def test_round_trip_of_random_configurations(cell: Cell) -> None:
    """Every non-singular target is solved (status OK, within limits) and reproduces its pose."""
    r = cell.robot
    q = _random_q(cell, 101)
    T = r.fk(q)
    qs, st = r.ik(T, q[0])                              # scattered targets: continuity across far jumps
    singular = st == IK_SINGULAR
    assert np.all(st[~singular] == IK_OK)              # 100 % outside the flagged rows
    assert singular.mean() < 0.05                      # flagged: |sin q5|, |sin psi| < 0.01 or t < 10 mm
    assert r.within_limits(qs).all()
    back = r.fk(qs)
    pos_mm = np.linalg.norm(back[:, :3, 3] - T[:, :3, 3], axis=1)
    rot_rad = rotation_error_rad(back[:, :3, :3], T[:, :3, :3])
    assert pos_mm.max() <= 1e-6 and rot_rad.max() <= 1e-9      # the issue asks 1e-6 m and 1e-6 rad
    ok = ~singular
    assert pos_mm[ok].max() <= 1e-8 and rot_rad[ok].max() <= 1e-11


def test_the_producing_configuration_is_one_of_the_8_branches(cell: Cell) -> None:
    r = cell.robot
    cf = r.closed_form
    assert cf is not None
    q = _random_q(cell, 102)
    qb, _ok, reach, sing = cf.branches(r.fk_flange(q))
    d = qb - q[:, None, :]
    d -= 2.0 * np.pi * np.rint(d / (2.0 * np.pi))
    nearest = np.min(np.max(np.abs(d), axis=2), axis=1)
    regular = ~sing.any(axis=1)
    assert np.all(reach.sum(axis=1) >= 2)
    assert nearest[regular].max() < 1e-9
    assert nearest.max() < 1e-5                          # singular rows: still the same configuration
    for b in range(8):                                    # and every branch found is a solution
        Tb = r.fk_flange(qb[reach[:, b], b])
        np.testing.assert_allclose(Tb[:, :3, 3], r.fk_flange(q[reach[:, b]])[:, :3, 3], atol=1e-7)


def test_tracking_mode_equals_the_full_8_branch_rule(cell: Cell) -> None:
    """The fast path (one branch while provably nearest) picks what the full 8-branch rule picks."""
    r = cell.robot
    s = np.linspace(0.0, 1.0, 3000)[:, None]
    span = np.minimum(r.upper_rad, np.pi) - np.maximum(r.lower_rad, -np.pi)
    # +-15 % of each range about home: away from the folded / stretched elbow, where the two elbows meet
    smooth = cell.home_q_rad + 0.15 * span * np.sin(2 * np.pi * s * np.array([1.0, 1.5, 0.7, 2.0, 1.2, 3.0]))
    smooth = np.clip(smooth, r.lower_rad, r.upper_rad)
    scattered = _random_q(cell, 103)[:3000]
    T = r.fk(np.concatenate([smooth, scattered, smooth[::-1]]))
    assert_tracking_equals_full_rule(r, T, smooth)
