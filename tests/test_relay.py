"""``fabric-cli relay``: a router process linked to the hub, for dashboards. Telemetry and queries cross it."""
from __future__ import annotations

import json
import queue
import subprocess
import sys
import time
import uuid

import msgpack
import pytest
import zenoh

from fabric import schemas as s
from fabric.client import Client
from fabric.services.supervisor import SupervisorService
from fabric.wire import codec
from fabric.wire.config import SessionSettings

from support.loopback import free_port, relay_process

POSE = s.Pose(seq=1, t_sim_s=2.0, q_deg=[0.0] * 6, xyz_mm=[1.0, 2.0, 3.0], quat_wxyz=[1.0, 0.0, 0.0, 0.0],
              base_xyz_mm=[4.0, 5.0, 6.0])


def relay_cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "fabric.cli.main", "relay", *args]


@pytest.fixture
def relay(hub, settings):
    """A relay process listening on a free port, linked to the test's hub."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    with relay_process("--listen", ep, "--connect", settings.connect[0]):
        yield ep


def router(endpoint: str) -> subprocess.Popen:
    """``fabric-cli router``: a hub as a process of its own (so that it can be killed)."""
    hub = subprocess.Popen([sys.executable, "-m", "fabric.cli.main", "router", "--listen", endpoint],
                           stdout=subprocess.PIPE, text=True)
    assert "fabric hub listening" in hub.stdout.readline()
    return hub


def plain_monitor(endpoint: str) -> zenoh.Session:
    """A dashboard as a third party writes it: plain zenoh, a client of the relay."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def test_a_dashboard_on_the_relay_gets_telemetry_and_answers(session, settings, relay):
    supervisor = SupervisorService(session, settings.cell)
    supervisor.start()
    got: queue.Queue = queue.Queue()
    try:
        with Client.connect(SessionSettings(connect=[relay], cell=settings.cell)) as dash, \
                plain_monitor(relay) as monitor:
            dash.wait_alive(("supervisor",), deadline_s=30)            # liveliness crosses the relay
            assert dash.call("supervisor", "jobs").jobs == []           # and a query and its reply
            key = dash.keys.topic("station", "pose")
            monitor.declare_subscriber(key, lambda sample: got.put(sample.payload.to_bytes()))
            deadline, data = time.monotonic() + 30, None
            while data is None and time.monotonic() < deadline:        # until the subscription has crossed
                session.put(key, codec.encode(POSE))
                try:
                    data = got.get(timeout=0.2)
                except queue.Empty:
                    pass
            assert data is not None and msgpack.unpackb(data)["xyz_mm"] == [1.0, 2.0, 3.0]
    finally:
        supervisor.close()


def test_a_relay_on_a_taken_port_says_so_in_one_line(relay):
    out = subprocess.run(relay_cli("--listen", relay), capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and "cannot start the router" in out.stderr and "Address already in use" in out.stderr
    assert "Traceback" not in out.stderr


@pytest.mark.parametrize("args, says", [
    ((), "a relay needs --listen ENDPOINT"),
    (("--listen", "tcp/127.0.0.1:7447", "--connect", "tcp/127.0.0.1:7447"), "listens elsewhere than the hub"),
    (("--listen", "tls/127.0.0.1:7448", "--secure", "no-such-dir"), "make the folder with 'fabric-cli auth init"),
])
def test_a_relay_refuses_what_it_cannot_be(args, says):
    out = subprocess.run(relay_cli(*args), capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and says in out.stderr + out.stdout


def test_a_relay_links_again_to_a_restarted_hub(tmp_path):
    """The hub is killed (-9) and started again: the relay rejoins it by itself, and a dashboard that stayed
    connected to the relay sees the services that joined the new hub."""
    hub_ep, relay_ep = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    cell = f"r{uuid.uuid4().hex[:8]}"
    hub = router(hub_ep)
    supervisor = None
    try:
        with relay_process("--listen", relay_ep, "--connect", hub_ep), \
                Client.connect(SessionSettings(connect=[relay_ep], cell=cell)) as dash:
            hub.kill()
            hub.wait()
            hub = router(hub_ep)
            supervisor = subprocess.Popen([sys.executable, "-m", "fabric.cli.main", "serve", "supervisor",
                                           "--connect", hub_ep, "--cell", cell, "--data-dir", str(tmp_path)])
            dash.wait_alive(("supervisor",), deadline_s=30)
            assert dash.call("supervisor", "jobs").jobs == []
    finally:
        for proc in (supervisor, hub):
            if proc is not None:
                proc.terminate()
                proc.wait(timeout=30)
