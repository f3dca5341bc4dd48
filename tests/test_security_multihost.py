"""Two hosts over TLS: the secured hub on one network namespace, services split over both, roles enforced.

As ``test_multihost.py`` (same hosts, same split), but every process holds credentials from
``fabric-cli auth init`` made for the hub's address: the hub (``router --secure``) listens on TLS only,
services join with the services' config, the operator's CLI on host B prints a job that crosses the
link both ways, and a monitor on host B is refused a command while it reads the station.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess

import pytest

from fabric.demo import sample_model
from fabric.security.credentials import Credentials

from test_multihost import ADDR_A, ADDR_B, fabric, hosts  # noqa: F401  (the fixture)

pytestmark = [pytest.mark.timeout(300),
              pytest.mark.skipif(os.geteuid() != 0 or shutil.which("ip") is None,
                                 reason="needs root and iproute2 for network namespaces")]


def test_a_print_job_across_two_hosts_over_tls(hosts, tmp_path):  # noqa: F811
    a, b, procs = hosts
    creds = Credentials.init(tmp_path / "creds", hub=f"tls/{ADDR_A}:7447")
    assert creds.listen_endpoints() == ["tls/0.0.0.0:7447"]
    procs.append(subprocess.Popen(fabric(a, "router", "--secure", str(creds.root)),
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT))
    assert b"listening" in procs[-1].stdout.readline()
    service = ["--cell", "tlshost", "--config", str(creds.config("service"))]
    for ns, names in ((a, ("station", "planner", "collision")), (b, ("slicer", "supervisor"))):
        for name in names:
            procs.append(subprocess.Popen(fabric(ns, "serve", name, *service, "--log-level", "WARNING",
                                                 "--data-dir", str(tmp_path / ns)),
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))

    def cli_b(*args: str, role: str = "operator") -> subprocess.CompletedProcess:
        return subprocess.run(fabric(b, *args, "--cell", "tlshost", "--config", str(creds.config(role)), "--json"),
                              capture_output=True, text=True, timeout=240)

    st = cli_b("status", "--wait", "90")
    assert st.returncode == 0, st.stdout + st.stderr
    assert all(s["alive"] for s in json.loads(st.stdout)["services"])
    job = cli_b("job", "submit", str(sample_model()), "--profile", "robot-1.2mm", "--start", "--rtf", "0",
                "--follow", "--timeout", "180")
    assert job.returncode == 0, job.stdout + job.stderr
    assert json.loads(job.stdout)["job"]["state"] == "finished"

    refused = cli_b("home", role="monitor")
    assert refused.returncode != 0 and "forbidden" in refused.stdout + refused.stderr
    assert cli_b("position", role="monitor").returncode == 0
    plain = subprocess.run(fabric(b, "status", "--cell", "tlshost", "--connect", f"tcp/{ADDR_A}:7447"),
                           capture_output=True, text=True, timeout=60)
    assert plain.returncode != 0 and "secured hub" in plain.stdout + plain.stderr
