"""The suite holds on any CPU: the C-against-numpy and IK tests pass with numpy limited to older kernels, and
the same G-code plans to the same joints, IK statuses, rotations about the nozzle and quaternions whichever
kernels numpy takes.

numpy picks its SIMD kernels by CPU (``support.kernels``); AVX-512's round some results otherwise than AVX2's
and libm's. This machine's best kernels run in the rest of the suite; here the tests that compare two
implementations, and a plan on every built-in cell, run again under ``NPY_DISABLE_CPU_FEATURES`` masks that
take numpy back one dispatch group and two (on an AVX-512 machine: without X86_V4, without X86_V3). A
machine whose best group is older runs fewer masks; one with none runs only the rest of the suite.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from support.kernels import ENV, older_kernel_masks

TESTS = Path(__file__).resolve().parent
MASKS = older_kernel_masks()
# every test that compares C with numpy, or two IK paths (the tracking and the full branch rule); the closed forms
# against reference solvers (test_ik_opw, _ur, _panda) differ by rounding only, and their plans' decisions are
# compared below
CROSS_CHECKS = ["test_nozzle_native.py", "test_native_track.py", "test_chain_native.py", "test_lookahead_native.py",
                "test_numtext.py", "test_native_lexer.py", "test_native_types.py", "test_nozzle_frames.py",
                "test_ik_roundtrip.py"]
JOINT_TOL_RAD = 1e-9      # rounding moves a joint by ~1e-15 rad; another branch or wrist flip moves it by > 0.1


def _env(mask: str | None) -> dict[str, str]:
    env = dict(os.environ)
    env.pop(ENV, None)
    if mask is not None:
        env[ENV] = mask
    return env


@pytest.mark.timeout(300)
@pytest.mark.parametrize("name", sorted(MASKS) or [pytest.param("none", marks=pytest.mark.skip("no older kernels"))])
def test_the_cross_checks_pass_with_older_kernels(name: str) -> None:
    res = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:randomly",
                          *CROSS_CHECKS], cwd=TESTS, env=_env(MASKS[name]), capture_output=True, text=True,
                         timeout=280)
    if res.returncode != 0:
        pytest.fail(f"{ENV}='{MASKS[name]}':\n{res.stdout[-6000:]}{res.stderr[-2000:]}", pytrace=False)


@pytest.mark.timeout(240)
def test_the_same_gcode_plans_to_the_same_decisions_with_every_kernel(tmp_path: Path) -> None:
    runs: dict[str, dict[str, np.ndarray]] = {}
    for name, mask in [("this CPU's best", None), *sorted(MASKS.items())]:
        out = tmp_path / f"{len(runs)}.npz"
        subprocess.run([sys.executable, str(TESTS / "support" / "plan_signature.py"), str(out)], env=_env(mask),
                       check=True, timeout=200)
        with np.load(out) as data:
            runs[name] = {k: data[k] for k in data.files}
    best = runs.pop("this CPU's best")
    assert any(k.endswith("/status") and (v == 0).mean() > 0.99 for k, v in best.items())   # plans, not failures
    for name, run in runs.items():
        assert run.keys() == best.keys()
        for key, want in best.items():
            got = run[key]
            if key.endswith(("/status", "/rot_deg")):
                np.testing.assert_array_equal(got, want, err_msg=f"{key} {name}")
            else:                                   # joints, quaternions (a sign flip is 2 apart)
                np.testing.assert_allclose(got, want, rtol=0, atol=JOINT_TOL_RAD, err_msg=f"{key} {name}")
