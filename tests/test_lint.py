"""ruff and mypy, configured in pyproject.toml, are clean: on fabric/, tests/ and tools/ (ruff) and fabric/ (mypy).

Both run as the developer runs them, from the repository root, so the configuration read is the project's. mypy
keeps its incremental cache in ``.mypy_cache`` (shared with a hand-run ``mypy``): a cold run takes about 30 s on
two busy cores, a warm one about a second.
"""
from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RUFF_PATHS = ("fabric", "tests", "tools")
COLD_MYPY_S = 240.0      # several times a cold run measured on two cores shared with other work


def _run(tool: str, *args: str, timeout_s: float) -> subprocess.CompletedProcess[str]:
    if importlib.util.find_spec(tool) is None:
        pytest.skip(f"{tool} is not installed (pip install -e '.[test]' brings it)")
    return subprocess.run([sys.executable, "-m", tool, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout_s)


@pytest.mark.timeout(120)
def test_ruff_is_clean():
    res = _run("ruff", "check", "--no-fix", "--output-format=concise", *RUFF_PATHS, timeout_s=100.0)
    if res.returncode != 0:
        pytest.fail(f"ruff check {' '.join(RUFF_PATHS)}:\n{res.stdout}{res.stderr}", pytrace=False)


@pytest.mark.timeout(COLD_MYPY_S + 60)
def test_mypy_is_clean():
    res = _run("mypy", timeout_s=COLD_MYPY_S)     # files and settings: [tool.mypy] in pyproject.toml
    if res.returncode != 0:
        pytest.fail(f"mypy:\n{res.stdout}{res.stderr}", pytrace=False)


def test_no_private_name_crosses_a_module():
    """A module's ``_names`` are its own: another module that needs one asks for a public name (the seams of
    ``tools/check_seams.py``, on fabric/ and tools/)."""
    res = subprocess.run([sys.executable, str(ROOT / "tools" / "check_seams.py")], cwd=ROOT, capture_output=True,
                         text=True, timeout=60)
    if res.returncode != 0:
        pytest.fail(f"private names crossing modules:\n{res.stdout}{res.stderr}", pytrace=False)
