"""The C helpers' build: cached by source and compiler, and a Python path wherever they cannot be had."""
from __future__ import annotations

import logging
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fabric import native
from fabric.planning.post import numtext


@pytest.fixture
def fresh(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An empty cache folder and nothing loaded yet."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(native, "_loaded", {})
    return tmp_path / "cache" / "am-fabric" / "native"


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler here")
def test_built_once_then_reused(fresh: Path) -> None:
    first = native.build("numtext")
    assert first.parent == fresh and first.exists()
    made = first.stat().st_mtime_ns
    assert native.build("numtext") == first and first.stat().st_mtime_ns == made
    assert [p.name for p in fresh.iterdir()] == [first.name]          # no temporary file left behind
    assert native.library("numtext") is not None


def test_no_compiler_means_the_python_path(fresh: Path, monkeypatch: pytest.MonkeyPatch,
                                           caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setenv("CC", "no-such-compiler")
    with caplog.at_level(logging.WARNING, logger="fabric.native"):
        assert native.library("numtext") is None
    assert "no C compiler (no-such-compiler)" in caplog.text


def test_a_failing_compiler_means_the_python_path(fresh: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                  caplog: pytest.LogCaptureFixture) -> None:
    cc = tmp_path / "broken-cc"
    cc.write_text("#!/bin/sh\necho 'numtext.c:1: error: broken on purpose' >&2\nexit 1\n")
    cc.chmod(cc.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("CC", str(cc))
    with caplog.at_level(logging.WARNING, logger="fabric.native"):
        assert native.library("numtext") is None
    assert "broken on purpose" in caplog.text
    assert not fresh.exists() or not any(fresh.iterdir())           # nothing half-built left


def test_switched_off(fresh: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FABRIC_NATIVE", "0")
    assert native.library("numtext") is None
    assert not fresh.exists()


def test_csv_text_is_the_same_without_the_helper(tmp_path: Path) -> None:
    """A process with the helper off (FABRIC_NATIVE=0) writes the same rows as one with it."""
    code = ("import sys, numpy as np\n"
            "from fabric.planning.post.numtext import FixedColumn, format_rows\n"
            "v = np.random.default_rng(3).normal(0, 500, 5000)\n"
            "sys.stdout.buffer.write(format_rows([FixedColumn(np.arange(5000), 0), FixedColumn(v, 4), b'']))\n")
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}
    on = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, check=True).stdout
    off = subprocess.run([sys.executable, "-c", code], env={**env, "FABRIC_NATIVE": "0"}, capture_output=True,
                         check=True).stdout
    v = np.random.default_rng(3).normal(0, 500, 5000)
    assert on == off == "".join(f"{i},{x:.4f},\n" for i, x in enumerate(v.tolist())).encode()
    assert numtext.format_rows([numtext.FixedColumn(v, 4)]) == "".join(f"{x:.4f}\n" for x in v.tolist()).encode()


def test_the_module_builds_ahead(tmp_path: Path) -> None:
    """``python -m fabric.native`` (run by tools/setup-env) says where each helper went, or why not, and exits 0."""
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}
    done = subprocess.run([sys.executable, "-m", "fabric.native"], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0
    assert "native helper numtext" in done.stdout + done.stderr


@pytest.mark.parametrize("name", ["kr6r700", "panda"])
def test_a_whole_plan_is_the_same_without_the_helpers(tmp_path: Path, name: str) -> None:
    """G-code -> plan -> CSV in a process with every helper and in one without (FABRIC_NATIVE=0): the same
    bytes. The raster's moves stray enough on both arms that the sag check splits some (the KR 6's axes
    about -z and -x, the Panda's chain walked in C)."""
    root = Path(__file__).resolve().parents[1]
    code = ("import sys\n"
            f"sys.path.insert(0, {str(root / 'tools' / 'bench')!r})\n"
            "from pathlib import Path\n"
            "from plan_bench import write_raster\n"
            "from fabric.planning import PlanOptions, plan_gcode_file\n"
            "from fabric.planning.post import write_csv\n"
            "from fabric.robot.cell import Cell\n"
            "g = Path(sys.argv[1]) / 'raster.gcode'\n"
            "write_raster(g, 30000, segment_mm=12.0)\n"
            f"res = plan_gcode_file(g, Cell.builtin({name!r}), PlanOptions(linear_tol_mm=0.05))\n"
            "print(res.stats.split_rows, file=sys.stderr)\n"
            "write_csv(res.program, sys.stdout)\n")
    runs = {}
    for flag in ("1", "0"):
        done = subprocess.run([sys.executable, "-c", code, str(tmp_path)], env={**os.environ, "FABRIC_NATIVE": flag},
                              capture_output=True, text=True, timeout=300, check=True)
        runs[flag] = done
    assert int(runs["1"].stderr.split()[-1]) > 0                    # moves were split
    assert runs["1"].stderr.split()[-1] == runs["0"].stderr.split()[-1]
    assert runs["1"].stdout == runs["0"].stdout
