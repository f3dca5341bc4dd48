"""`fabric-cli slice --layers curved` through the slicer service: multi-axis G-code out, typed errors back."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.gcode.reader import parse_gcode
from fabric.robot.cell import Cell
from fabric.services.collision import CollisionService
from fabric.services.planner import PlannerService
from fabric.services.slicer import SlicerService
from fabric.slicing.curved.shapes import arch
from fabric.wire.errors import BadRequest

pytestmark = pytest.mark.timeout(240)

AXIS_MOVE = re.compile(r"^G1 X\S+ Y\S+ Z\S+ I\S+ J\S+ K\S+ E\S+")


@pytest.fixture
def slicer(session, settings):
    service = SlicerService(session, settings.cell, (250.0, 250.0), 250.0)
    service.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("slicer",), deadline_s=20)
        yield service
    finally:
        service.close()


def test_fabric_cli_slices_curved_layers_into_the_multiaxis_dialect(slicer, session, settings, tmp_path):
    model = tmp_path / "arch.stl"
    model.write_bytes(arch().export(file_type="stl"))
    out = tmp_path / "arch.gcode"
    r = subprocess.run([sys.executable, "-m", "fabric.cli.main", "slice", str(model), "--layers", "curved",
                        "-o", str(out), "--json", *replace(settings, mode="client").to_args()],
                       capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr
    result = json.loads(r.stdout)
    assert result["backend"] == "builtin" and result["layers"] > 50
    text = out.read_text()
    assert text.startswith("; multiaxis: nozzle axis in I J K")
    assert "; curved: overhang_reduction_r" in text
    extruding = [ln for ln in text.splitlines() if ln.startswith("G1 X")]
    assert extruding and all(AXIS_MOVE.match(ln) for ln in extruding)

    fig = result["curved"]                              # the slice's figures travel with its result
    assert fig["overhang_mm2"] < 0.1 * fig["planar_overhang_mm2"] and fig["max_tilt_deg"] <= 45.0 + 1e-6

    # the reader takes the dialect: every move with its unit nozzle axis
    tp = parse_gcode(text)
    assert tp.multiaxis and tp.axis is not None and len(tp.axis) == len(tp)
    np.testing.assert_allclose(np.linalg.norm(tp.axis, axis=1), 1.0, atol=1e-12)
    assert np.degrees(np.arccos(tp.axis[:, 2].min())) <= 45.0 + 0.1
    # and the planner plans it with the tilted nozzle: every target reached on the multi-axis cell; and the
    # whole print is collision-free there: where the layers from both feet meet over the crown the creases are
    # rounded and the nozzle turned clear of the other side (without either, its nozzle hit the part there)
    cell = Cell.builtin("irb140-multiaxis")
    planner = PlannerService(session, settings.cell, cell, data_dir=tmp_path / "planner")
    collision = CollisionService(session, settings.cell, cell, data_dir=tmp_path / "collision")
    planner.start()
    collision.start()
    try:
        r = subprocess.run([sys.executable, "-m", "fabric.cli.main", "plan", str(out), "--json",
                            *replace(settings, mode="client").to_args()], capture_output=True, text=True, timeout=120)
        check = subprocess.run([sys.executable, "-m", "fabric.cli.main", "check", str(out), "--json",
                                *replace(settings, mode="client").to_args()], capture_output=True, text=True,
                               timeout=180)
    finally:
        collision.close()
        planner.close()
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)["summary"]
    assert summary["runnable"] and summary["feasible_r"] == 1.0 and summary["layers"] == result["layers"]
    assert "Traceback" not in r.stderr
    assert check.returncode == 0, check.stdout[-2000:] + check.stderr[-2000:]
    report = json.loads(check.stdout)["collisions"]
    assert report["collision_free"] is True and report["first_hit"] is None, report


def test_curved_layers_on_an_external_backend_are_refused_at_once(slicer, settings):
    with Client.connect(settings) as client, pytest.raises(BadRequest, match="builtin"):
        client.slice(s.SliceRequest(model=b"solid x\nendsolid x\n", filename="x.stl", backend="prusaslicer",
                                    layers="curved"))
