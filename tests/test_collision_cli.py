"""`fabric-cli check` and the job pipeline's check, against the cell's processes, as a user runs them."""
from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
from test_collision_certify import TOWER_A, TOWER_B, towers_gcode, travel_through

from fabric import schemas as s
from fabric.client import Client
from fabric.demo import sample_model
from fabric.wire.errors import CollisionError

pytestmark = pytest.mark.timeout(300)


def cli(settings, *args: str, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fabric.cli.main", *args,
                           *replace(settings, mode="client").to_args()],
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def settings(running_cell):
    return running_cell.settings


@pytest.fixture(scope="module")
def through(tmp_path_factory) -> tuple[Path, int]:
    text, line = travel_through(40.0)
    path = tmp_path_factory.mktemp("check") / "towers-through.gcode"
    path.write_text(text)
    return path, line


def test_check_reports_the_travel_through_a_tower_and_exits_2(settings, through):
    path, line = through
    r = cli(settings, "check", str(path))
    assert r.returncode == 2, r.stderr
    first = r.stdout.splitlines()[0]
    assert first.startswith(f"COLLISION at G-code line {line} (travel, layer 100): tool_")
    assert "hits the part (a bead of layer" in first and "with the nozzle at (" in first and "t = " in first
    r = cli(settings, "check", str(path), "--json")
    assert r.returncode == 2, r.stderr
    out = json.loads(r.stdout)
    hit = out["collisions"]["first_hit"]
    assert hit["gcode_line"] == line and hit["kind"] == "travel" and hit["body_b"] == "part"
    assert hit["layer"] == 99 and len(hit["xyz_mm"]) == 3 and hit["t_s"] > 0
    assert out["summary"]["program_id"]


def test_check_certifies_a_clean_print(settings, tmp_path):
    path = tmp_path / "towers.gcode"
    path.write_text(towers_gcode([TOWER_A, TOWER_B], height_mm=10.0))
    r = cli(settings, "check", str(path))
    assert r.returncode == 0, r.stderr
    first = r.stdout.splitlines()[0]
    assert first.startswith("collision-free, certified clearance 0.")
    assert "tool_tip" in first and "layer 1" in first
    assert "not checked: tool_tip: r 4 mm x 1 mm" in r.stdout


def test_check_slices_a_model_first(settings):
    r = cli(settings, "check", str(sample_model()), "--profile", "robot-1.2mm", "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)["collisions"]
    assert rep["collision_free"] and rep["min_distance_mm"] > 0.1 and rep["beads"] > 1000


@pytest.mark.parametrize("case,code", [("missing", "bad_request"), ("empty", "gcode"), ("garbled", "gcode"),
                                       ("unreachable", "unreachable"), ("tolerance", "validation")])
def test_check_bad_input_gets_a_typed_error(settings, tmp_path, case, code):
    path = tmp_path / f"{case}.gcode"
    args = []
    if case == "empty":
        path.write_text("")
    elif case == "garbled":
        path.write_text("G21\nG90\nM83\nG1 X10 X20 E1\n")
    elif case == "unreachable":
        path.write_text("G21\nG90\nM83\nM104 S210\nM109 S210\nG1 Z0.3 F600\nG1 X5000 Y5000 E1 F1200\n")
    elif case == "tolerance":
        path.write_text(towers_gcode([TOWER_A], height_mm=1.0))
        args = ["--tolerance", "50"]
    r = cli(settings, "check", str(path), *args)
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert r.stderr.startswith(f"error [{code}]: "), r.stderr
    r = cli(settings, "check", str(path), *args, "--json")
    assert r.returncode == 1 and json.loads(r.stdout)["error"]["code"] == code


def test_a_refused_job_never_loads(settings, through):
    path, line = through
    with Client.connect(replace(settings, mode="client")) as client:
        acc = client.submit(s.JobSubmit(model=path.read_bytes(), filename=path.name, start=True, rtf=0.0))
        with pytest.raises(CollisionError) as err:                # the job fails with the check's hit
            client.wait_print_job(acc.job_id, lambda r: False, timeout=240)
        assert err.value.details["gcode_line"] == line and err.value.details["kind"] == "travel"
        rec = client.job(acc.job_id)
        assert rec.state == "failed" and rec.error is not None and rec.error.code == "collision"
        assert f"G-code line {line} (travel, layer 100)" in rec.error.message
        assert rec.collisions is not None and rec.collisions.first_hit.gcode_line == line
        state = client.state()
        assert state.program_id != rec.program_id and state.job_id != acc.job_id
        assert not any(e.data.get("job_id") == acc.job_id for e in client.events(0).events)
