"""fabric-cli as a user runs it, against the cell's processes: outputs, exports and clear errors."""
from __future__ import annotations

import csv
import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import trimesh

from fabric.demo import sample_model

pytestmark = pytest.mark.timeout(300)


def cli(settings, *args: str, timeout: float = 180) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fabric.cli.main", *args,
                           *replace(settings, mode="client").to_args()],
                          capture_output=True, text=True, timeout=timeout)


def local(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fabric.cli.main", *args], capture_output=True, text=True,
                          timeout=120)


@pytest.fixture(scope="module")
def settings(running_cell):
    return running_cell.settings


@pytest.fixture(scope="module")
def gcode(settings, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("cli") / "part.gcode"
    r = cli(settings, "slice", str(sample_model()), "-o", str(out), "--profile", "robot-1.2mm")
    assert r.returncode == 0, r.stderr
    assert "layers" in r.stdout
    # piped, the progress is a line per stage, not percentages glued together by carriage returns
    assert "\r" not in r.stderr and r.stderr.splitlines().count("  slicing") == 1, r.stderr
    return out


def test_slice_writes_gcode_with_layer_markers(gcode):
    text = gcode.read_text()
    assert ";LAYER_CHANGE" in text and "M83" in text


@pytest.mark.slicers
def test_slice_with_prusaslicer_backend(settings, tmp_path):
    out = tmp_path / "p.gcode"
    r = cli(settings, "slice", str(sample_model()), "-o", str(out), "--backend", "prusaslicer", "--json")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert res["backend"] == "prusaslicer" and res["layers"] > 10 and out.stat().st_size > 1000


def _box(path: Path, size_mm: float) -> Path:
    trimesh.creation.box((size_mm, size_mm, 10.0)).export(path)
    return path


@pytest.mark.parametrize("case,code,words", [
    ("empty", "mesh", "empty"),
    ("truncated", "mesh", "truncated"),
    ("open", "mesh", ""),
    ("huge", "placement", "plate"),
    ("profile", "profile", "nozzle_size"),
])
def test_slice_broken_inputs_get_clear_errors(settings, tmp_path, case, code, words):
    args = []
    if case == "empty":
        model = tmp_path / "empty.stl"
        model.write_bytes(b"")
    elif case == "truncated":
        model = tmp_path / "cut.stl"
        model.write_bytes(sample_model().read_bytes()[:3000])
    elif case == "open":
        model = tmp_path / "open.stl"
        sheet = trimesh.Trimesh(vertices=[[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]], faces=[[0, 1, 2]])
        sheet.export(model)
    elif case == "huge":
        model = _box(tmp_path / "huge.stl", 300.0)
    else:
        model = sample_model()
        args = ["--set", "nozzle_size=0.4"]
    r = cli(settings, "slice", str(model), "-o", str(tmp_path / "x.gcode"), *args)
    assert r.returncode == 1
    assert f"error [{code}]" in r.stderr and words.lower() in r.stderr.lower(), r.stderr
    rj = cli(settings, "slice", str(model), "-o", str(tmp_path / "x.gcode"), "--json", *args)
    assert json.loads(rj.stdout)["error"]["code"] == code


def test_plan_exports_rapid_and_csv(settings, gcode, tmp_path):
    mod, table = tmp_path / "part.mod", tmp_path / "part.csv"
    r = cli(settings, "plan", str(gcode), "--rapid", str(mod), "--csv", str(table), "--json")
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)["summary"]
    assert summary["runnable"] and summary["layers"] > 10 and summary["estimate_s"] > 0
    text = mod.read_text()
    assert "MODULE" in text and "MoveL" in text and "ENDMODULE" in text
    with table.open() as fh:
        rows = list(csv.DictReader(fh))
    for col in ("gcode_line", "x_mm", "y_mm", "z_mm", "q1_deg", "q6_deg", "speed_mm_s", "extrude", "t_s"):
        assert col in rows[0], col
    assert len(rows) == summary["targets"]
    t = np.array([float(r["t_s"]) for r in rows])
    assert np.all(np.diff(t) >= -1e-9) and t[-1] == pytest.approx(summary["estimate_s"], abs=1e-3)


def test_plan_unreachable_names_the_line(settings, tmp_path):
    bad = tmp_path / "far.gcode"
    bad.write_text("G21\nG90\nM83\nG1 Z0.3 F600\nG1 X100 Y100 E1\nG1 X2000 Y100 E5 ; far off the plate\n")
    r = cli(settings, "plan", str(bad))
    assert r.returncode == 2
    assert "line 6" in r.stdout and "off the plate" in r.stdout and "--allow-off-plate" in r.stdout
    assert "cycle time n/a" in r.stdout and "-1.0" not in r.stdout
    assert "filament 1.75 mm (ASSUMED)" in r.stdout and "warning: the G-code states no filament diameter" in r.stdout
    r = cli(settings, "plan", str(bad), "--allow-off-plate", "--filament-diameter", "2.85")
    assert r.returncode == 2 and "line 6: out of reach" in r.stdout and "(allowed)" in r.stdout
    assert "filament 2.85 mm (as asked)" in r.stdout and "warning" not in r.stdout
    r = cli(settings, "plan", str(bad), "--csv", str(tmp_path / "x.csv"), "--rapid", str(tmp_path / "x.mod"))
    assert r.returncode == 1 and "error [unreachable]" in r.stderr and "line 6" in r.stderr
    # all or nothing: the CSV (which could be written) is not left either, nor any temporary file
    assert sorted(p.name for p in tmp_path.iterdir()) == ["far.gcode"]


def test_plan_garbled_gcode_names_the_line(settings, tmp_path):
    bad = tmp_path / "bad.gcode"
    bad.write_text("G21\nG90\nG1 X1.2.3 Y4\n")
    r = cli(settings, "plan", str(bad))
    assert r.returncode == 1 and "error [gcode]" in r.stderr and "line 3" in r.stderr
    # the error starts its own line, not the end of the progress line drawn in place before it
    assert any(line.startswith("error [gcode]") for line in r.stderr.split("\n")), r.stderr


def test_operator_commands_human_output(settings):
    assert "TCP" in cli(settings, "position").stdout
    t = cli(settings, "time")
    assert t.returncode == 0 and "elapsed" in t.stdout and "remaining" in t.stdout
    ready = cli(settings, "ready")
    assert "services alive" in ready.stdout and ("READY" in ready.stdout)
    st = cli(settings, "status")
    assert st.returncode == 0 and "station" in st.stdout and "alive" in st.stdout


def test_cells_lists_the_cell_and_an_unknown_cell_is_named(settings):
    r = cli(settings, "cells", "--json")
    assert r.returncode == 0, r.stderr
    cells = {c["cell"]: c for c in json.loads(r.stdout)}
    assert cells[settings.cell]["complete"] and len(cells[settings.cell]["services"]) == 5
    r = cli(replace(settings, cell="nosuchcell"), "status")
    assert r.returncode == 3
    assert "no service of cell 'nosuchcell' is on the fabric" in r.stdout and settings.cell in r.stdout
