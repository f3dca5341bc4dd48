"""Multi-axis printing end to end (issue 21): a model submitted with curved layers prints on the twin with a tilted
nozzle, through the five service processes a user's ``fabric-cli up --cell-config irb140-multiaxis`` starts.

slice (curved layers, multi-axis G-code) -> plan (every move with its nozzle axis) -> collision check (the
tilted tool against the part as printed) -> station (beads laid along the axis) -> the as-printed mesh and
the job record; then the same file submitted as planar to compare what the operator sees.
"""
from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from fabric import schemas as s
from fabric.cli.up import CellProcesses
from fabric.client import Client
from fabric.client.follow import follow_print
from fabric.slicing.curved.shapes import dome

from support.loopback import make_settings

pytestmark = pytest.mark.timeout(420)

CELL = "irb140-multiaxis"
CELL_SERVICES = ("station", "slicer", "planner", "collision")


@pytest.fixture(scope="module")
def cell_up(tmp_path_factory):
    st = make_settings()
    cell = CellProcesses(st, log_dir=tmp_path_factory.mktemp("curved-logs"),
                         data_dir=tmp_path_factory.mktemp("curved-data"),
                         extra_args={svc: ["--cell-config", CELL] for svc in CELL_SERVICES})
    cell.start(deadline_s=120.0)
    try:
        yield cell
    finally:
        cell.stop()


def test_a_dome_prints_along_curved_layers_with_a_tilted_nozzle(cell_up, tmp_path) -> None:
    part = tmp_path / "dome.stl"
    part.write_bytes(dome(radius_mm=10.0, height_mm=5.0, rings=12, sections=40).export(file_type="stl"))
    args = cell_up.client_settings.to_args()
    r = subprocess.run([sys.executable, "-m", "fabric.cli.main", "job", "submit", str(part), "--layers", "curved",
                        "--start", "--rtf", "0", *args], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    job_id = r.stdout.split()[1]
    with Client.connect(cell_up.client_settings) as client:
        client.wait_print_job(job_id, lambda rec: rec.state in ("printing", "loaded", "finished", "failed"),
                              timeout=300)
        end = follow_print(client, timeout_s=300)
        rec = client.wait_print_job(job_id, lambda rec: False, timeout=20)
        assert end.kind == "finished", rec.error
        assert rec.state == "finished" and rec.layers == "curved"
        assert rec.plan is not None and rec.plan.runnable and rec.plan.feasible_r == 1.0
        assert rec.collisions is not None and rec.collisions.collision_free
        assert rec.deposited_mm3 == pytest.approx(rec.plan.extruded_mm3, rel=1e-6)

        # the beads were laid along tilted nozzle axes, and the as-printed part follows the dome
        page = client.call("station", "beads", s.BeadsQuery(first=0, limit=s.pipeline.MAX_BEADS_PAGE))
        tilt = np.degrees(np.arccos(np.clip(page.axis[:, 2], -1.0, 1.0)))
        assert len(page.axis) == len(page.row) and tilt.max() > 15.0 and tilt.max() <= 45.0 + 1e-6
        art = client.mesh("stl")
        mesh = trimesh.load(io.BytesIO(art.data), file_type="stl")
        assert mesh.volume == pytest.approx(rec.deposited_mm3, rel=0.02)

    # what the operator reads: the job with its layers, and the slice's figures on the command line
    shown = subprocess.run([sys.executable, "-m", "fabric.cli.main", "job", "show", job_id, *args],
                           capture_output=True, text=True, timeout=30)
    assert shown.returncode == 0 and "curved layers" in shown.stdout, shown.stdout + shown.stderr
