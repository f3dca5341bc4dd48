"""The CLI stays thin: building the parser and running a query import no service, twin or heavy library."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from fabric.cli.main import build_parser, service_parser

pytestmark = pytest.mark.timeout(120)

HEAVY = ("pinocchio", "scipy", "trimesh", "coal", "ruckig", "textual", "matplotlib",
         "fabric.sim", "fabric.services", "fabric.robot", "fabric.planning", "fabric.slicing")

# Builds the parser, prints --help, resolves `position` and runs its handler on a stand-in client
# (the same formatting path as a real reply), then prints every module loaded.
PROBE = """
import contextlib, io, json, sys
from fabric import schemas as s
from fabric.cli.main import build_parser

class StandInClient:
    def position(self):
        return s.Pose(seq=1, t_sim_s=0.5, q_deg=[0.0] * 6, xyz_mm=[1.0, 2.0, 3.0], quat_wxyz=[1.0, 0.0, 0.0, 0.0],
                      base_xyz_mm=[4.0, 5.0, 6.0])

parser = build_parser()
out = io.StringIO()
with contextlib.redirect_stdout(out):
    parser.format_help()
    args = parser.parse_args(["position"])
    rc = args.run(StandInClient(), args)
sys.stderr.write(out.getvalue())
print(json.dumps({"rc": rc, "modules": sorted(sys.modules)}))
"""


def _heavy(modules: list[str]) -> list[str]:
    return [m for m in modules if any(m == h or m.startswith(h + ".") for h in HEAVY)]


def test_help_and_position_import_nothing_heavy():
    r = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert res["rc"] == 0 and "plate (1.00, 2.00, 3.00) mm" in r.stderr
    assert "fabric.client" in res["modules"]
    assert _heavy(res["modules"]) == []


def test_help_as_a_process_imports_nothing_heavy():
    r = subprocess.run([sys.executable, "-X", "importtime", "-m", "fabric.cli.main", "--help"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "serve" in r.stdout
    loaded = [line.rsplit("|", 1)[-1].strip() for line in r.stderr.splitlines() if line.startswith("import time:")]
    assert "fabric.cli.station_cmds" in loaded
    assert _heavy(loaded) == []


def test_serve_passes_the_service_options_to_the_service_parser():
    args = build_parser().parse_args(["serve", "slicer", "--connect", "tcp/127.0.0.1:1", "--build-height", "120"])
    assert args.service == "slicer"
    opts = service_parser(args.service).parse_args(args.service_args)
    assert opts.build_height == 120.0 and opts.connect == ["tcp/127.0.0.1:1"] and opts.log_level == "INFO"


def test_serve_rejects_an_unknown_service_and_an_unknown_option():
    with pytest.raises(SystemExit):
        build_parser().parse_args(["serve", "printer"])
    args = build_parser().parse_args(["serve", "supervisor", "--pose-hz", "5"])
    with pytest.raises(SystemExit):
        service_parser(args.service).parse_args(args.service_args)
