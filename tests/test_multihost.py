"""Two hosts: the cell split over two network namespaces joined by a veth link (root and iproute2 only).

Host A runs the hub, the station, the planner and the collision checker; host B
runs the slicer and the supervisor, and the operator's CLI. A print job crosses
the link both ways (model bytes to the slicer, G-code to the planner, programs
to the station) with no shared filesystem between the services' work.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import uuid

import pytest

from fabric.demo import sample_model

pytestmark = [pytest.mark.timeout(300),
              pytest.mark.skipif(os.geteuid() != 0 or shutil.which("ip") is None,
                                 reason="needs root and iproute2 for network namespaces")]

ADDR_A, ADDR_B = "10.254.77.1", "10.254.77.2"      # the test's own hosts, inside its own namespaces


def sh(*args: str) -> None:
    subprocess.run(args, check=True, capture_output=True, timeout=30)


@pytest.fixture
def hosts():
    tag = uuid.uuid4().hex[:6]
    a, b = f"fabA{tag}", f"fabB{tag}"
    try:
        sh("ip", "netns", "add", a)
        sh("ip", "netns", "add", b)
        sh("ip", "link", "add", f"va{tag}", "type", "veth", "peer", "name", f"vb{tag}")
        sh("ip", "link", "set", f"va{tag}", "netns", a)
        sh("ip", "link", "set", f"vb{tag}", "netns", b)
        for ns, dev, addr in ((a, f"va{tag}", ADDR_A), (b, f"vb{tag}", ADDR_B)):
            sh("ip", "-n", ns, "addr", "add", f"{addr}/30", "dev", dev)
            sh("ip", "-n", ns, "link", "set", dev, "up")
            sh("ip", "-n", ns, "link", "set", "lo", "up")
    except subprocess.CalledProcessError as exc:
        for ns in (a, b):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        pytest.skip(f"network namespaces not available here: {exc.stderr.decode(errors='replace').strip()}")
    procs: list[subprocess.Popen] = []
    yield a, b, procs
    for p in procs:
        p.terminate()
    for p in procs:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
    for ns in (a, b):
        subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def fabric(ns: str, *args: str) -> list[str]:
    return ["ip", "netns", "exec", ns, sys.executable, "-m", "fabric.cli.main", *args]


def test_a_print_job_across_two_hosts(hosts, tmp_path):
    a, b, procs = hosts
    hub = f"tcp/{ADDR_A}:7447"
    common = ["--cell", "twohost", "--connect", hub]
    procs.append(subprocess.Popen(fabric(a, "router", "--listen", hub, "--cell", "twohost"),
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT))
    assert b"listening" in procs[-1].stdout.readline()
    for ns, addr, names in ((a, ADDR_A, ("station", "planner", "collision")), (b, ADDR_B, ("slicer", "supervisor"))):
        for name in names:
            procs.append(subprocess.Popen(fabric(ns, "serve", name, *common, "--listen", f"tcp/{addr}:0",
                                                 "--log-level", "WARNING", "--data-dir", str(tmp_path / ns)),
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))

    def cli_b(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(fabric(b, *args, *common, "--json"), capture_output=True, text=True, timeout=240)

    st = cli_b("status", "--wait", "90")          # by liveliness, from host B, with a deadline
    assert st.returncode == 0, st.stdout + st.stderr
    assert all(s["alive"] for s in json.loads(st.stdout)["services"])

    job = cli_b("job", "submit", str(sample_model()), "--profile", "robot-1.2mm", "--start", "--rtf", "0",
                "--follow", "--timeout", "180")
    assert job.returncode == 0, job.stdout + job.stderr
    res = json.loads(job.stdout)
    assert res["job"]["state"] == "finished" and res["end"]["kind"] == "finished", json.dumps(res["job"])[:600]
    assert res["time"]["remaining_s"] == pytest.approx(0.0, abs=1e-6)
