"""Curved prints on shapes nobody tuned for (issue 38), end to end through the five service processes of
`fabric-cli up --cell-config irb140-multiaxis`: a hook curling away from the robot, a vase with a flared lip and
a bridge with a skewed span, each submitted as a model with `job submit --layers curved --start --rtf 0`.

Each plans runnable (every target reached: the slicer chose axes the cell's arm holds, so the hook's 2676
targets at A5's limit are gone), checks collision-free, prints on the twin to its end and deposits what was
planned, with the nozzle tilted; what the operator reads (`job show`) has its curved layers."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from fabric import schemas as s
from fabric.cli.up import CellProcesses
from fabric.client import Client
from fabric.client.follow import follow_print
from fabric.slicing.curved.shapes import OTHER_SHAPES

from support.loopback import make_settings

pytestmark = pytest.mark.timeout(600)

CELL = "irb140-multiaxis"
CELL_SERVICES = ("station", "slicer", "planner", "collision")
PRINT_S = 300.0              # a deadline for one shape from submission to the end of its print (about 40 s)


@pytest.fixture(scope="module")
def cell_up(tmp_path_factory):
    st = make_settings()
    cell = CellProcesses(st, log_dir=tmp_path_factory.mktemp("shapes-logs"),
                         data_dir=tmp_path_factory.mktemp("shapes-data"),
                         extra_args={svc: ["--cell-config", CELL] for svc in CELL_SERVICES})
    cell.start(deadline_s=120.0)
    try:
        yield cell
    finally:
        cell.stop()


@pytest.mark.parametrize("name", sorted(OTHER_SHAPES))
def test_a_shape_nobody_tuned_for_plans_runnable_and_prints_along_curved_layers(cell_up, tmp_path, name):
    part = tmp_path / f"{name}.stl"
    part.write_bytes(OTHER_SHAPES[name]().export(file_type="stl"))
    args = cell_up.client_settings.to_args()
    r = subprocess.run([sys.executable, "-m", "fabric.cli.main", "job", "submit", str(part), "--layers", "curved",
                        "--start", "--rtf", "0", *args], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    job_id = r.stdout.split()[1]
    with Client.connect(cell_up.client_settings) as client:
        try:
            rec = client.wait_print_job(job_id, lambda rec: rec.state in ("printing", "loaded", "finished", "failed"),
                                        timeout=PRINT_S)
            assert rec.state != "failed", rec.reason
            end = follow_print(client, timeout_s=PRINT_S)
            rec = client.wait_print_job(job_id, lambda rec: False, timeout=20)
            assert end.kind == "finished", rec.error
            # the last beads laid (the upper layers lean; the first ones lie flat on the plate)
            total = client.call("station", "beads", s.BeadsQuery(first=0, limit=1)).total
            page = client.call("station", "beads", s.BeadsQuery(first=max(total - s.pipeline.MAX_BEADS_PAGE, 0),
                                                                limit=s.pipeline.MAX_BEADS_PAGE))
        finally:
            client.clear_plate()              # the next shape prints on a clear plate
    assert rec.state == "finished" and rec.layers == "curved"
    assert rec.plan is not None and rec.plan.runnable and rec.plan.feasible_r == 1.0
    assert rec.plan.unreachable_by_joint == {} and rec.plan.first_unreachable is None
    assert rec.collisions is not None and rec.collisions.collision_free
    assert rec.deposited_mm3 == pytest.approx(rec.plan.extruded_mm3, rel=1e-6)
    tilt = np.degrees(np.arccos(np.clip(page.axis[:, 2], -1.0, 1.0)))
    assert tilt.max() > 10.0 and tilt.max() <= 45.0 + 0.01        # the G-code's I J K have 4 decimals
    shown = subprocess.run([sys.executable, "-m", "fabric.cli.main", "job", "show", job_id, *args],
                           capture_output=True, text=True, timeout=30)
    assert shown.returncode == 0 and "curved layers" in shown.stdout, shown.stdout + shown.stderr
