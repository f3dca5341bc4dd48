"""Checks shared by the IK tests of every family."""
from __future__ import annotations

import numpy as np

from fabric.robot.closed_form import ClosedFormIK
from fabric.robot.model import RobotModel


def assert_tracking_equals_full_rule(r: RobotModel, T: np.ndarray, smooth: np.ndarray,
                                     free_value: float | None = None) -> None:
    """The fast path (one branch while provably nearest) picks what the full 8-branch rule picks on poses
    ``T``, whose first ``len(smooth)`` rows are the smooth joint path ``smooth`` (kept in its configuration)."""
    assert r.closed_form is not None
    extra = () if free_value is None else (free_value,)
    fast = ClosedFormIK(r.closed_form.arm, r.lower_rad, r.upper_rad, r.tool_T, *extra)
    full = ClosedFormIK(r.closed_form.arm, r.lower_rad, r.upper_rad, r.tool_T, *extra)
    full.tracking = False
    qa, sa = fast.solve(T, smooth[0])
    qb, sb = full.solve(T, smooth[0])
    np.testing.assert_array_equal(sa, sb)
    np.testing.assert_allclose(qa, qb, atol=1e-12)
    np.testing.assert_allclose(qa[:len(smooth)], smooth, atol=1e-8)
