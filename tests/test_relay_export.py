"""``fabric-cli auth export DIR relay``: a relay host's own folder, and what a relay answers.

The folder holds only what a relay needs (the CA certificate, its own certificate for its host, the monitor's
credentials), never an operator's or a service's password or key; the relay runs from it alone (the hub's
address comes from it); every malformed file in it, or in a whole credentials folder, is one typed line. A
command through a relay is refused like the hub refuses it: ``[forbidden]``, one line, naming the relay.
"""
from __future__ import annotations

import base64
import json
import shutil
import ssl
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest
import zenoh

from fabric.security.credentials import Credentials
from fabric.security.hub import hub_zenoh_config
from fabric.security.relay import RelayFolder
from fabric.security.zconfigs import read_json5, write_json5
from fabric.services.supervisor import SupervisorService
from fabric.wire.config import SessionSettings

from support.loopback import free_port, relay_process

pytestmark = pytest.mark.timeout(180)


def cli(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fabric.cli.main", *args], capture_output=True, text=True,
                          timeout=timeout)


def one_line(done: subprocess.CompletedProcess, starts: str) -> str:
    """The command failed with exactly one line on stderr, starting with ``starts``; that line."""
    err = done.stderr.strip()
    assert done.returncode == 1, done.stdout + done.stderr
    assert "Traceback" not in err and err.splitlines() == [err], err
    assert err.startswith(starts), err
    return err


@pytest.fixture(scope="module")
def creds(tmp_path_factory) -> Credentials:
    return Credentials.init(tmp_path_factory.mktemp("creds") / "fabric", hub=f"tls/127.0.0.1:{free_port()}")


@pytest.fixture(scope="module")
def folder(creds, tmp_path_factory) -> RelayFolder:
    out = tmp_path_factory.mktemp("relay") / "relay-here"
    done = cli("auth", "export", str(creds.root), "relay", "--host", "127.0.0.1", "--listen",
               f"tls/127.0.0.1:{free_port()}", "-o", str(out), "--json")
    assert done.returncode == 0, done.stderr
    said = json.loads(done.stdout)
    assert said["hub"] == creds.hub_endpoints() and said["dir"] == str(out)
    return RelayFolder(out)


# --- the folder ----------------------------------------------------------------------------------------------

def _secrets(creds: Credentials) -> dict[str, bytes]:
    """What must never leave the hub's host: the operator's and services' passwords and keys, the hub's and
    the CA's keys (as files and as the base64 the configs inline)."""
    out = {}
    passwords = creds.read_passwords()
    for role in ("operator", "service"):
        out[f"{role} password"] = passwords[role].encode()
    for name, path in (("operator key", creds.key("operator")), ("service key", creds.key("service")),
                       ("hub key", creds.key("hub")), ("CA key", creds.ca_key)):
        pem = path.read_bytes()
        out[name] = b"".join(ln for ln in pem.splitlines() if not ln.startswith(b"-----"))
        out[name + " (inline)"] = base64.b64encode(pem)
    return out


def test_the_folder_holds_only_what_a_relay_needs(creds, folder) -> None:
    assert sorted(p.name for p in folder.root.iterdir()) == sorted(RelayFolder.FILES)
    for path in folder.root.iterdir():
        data = path.read_bytes().replace(b"\n", b"")
        for what, secret in _secrets(creds).items():
            assert secret not in data, f"{path.name} holds the {what}"
        if path.name not in ("ca.pem", "relay-cert.pem"):
            assert path.stat().st_mode & 0o077 == 0, f"{path.name} is readable by others"
    assert folder.root.stat().st_mode & 0o077 == 0
    assert folder.passwords.read_text() == f"monitor:{creds.read_passwords()['monitor']}\n"
    cert = ssl._ssl._test_decode_cert(str(folder.cert))        # type: ignore[attr-defined]
    assert cert["subject"] == ((("commonName", "relay"),),)
    assert ("IP Address", "127.0.0.1") in cert["subjectAltName"]
    assert folder.hub_endpoints() == creds.hub_endpoints()
    dash = read_json5(folder.dashboard)                          # a dashboard's config: to the relay
    assert dash["connect"]["endpoints"] == [f"tls/127.0.0.1:{folder.listen_endpoints()[0].rsplit(':', 1)[1]}"]
    assert dash["metadata"] == {"fabric_role": "monitor"}


def test_export_refuses_in_one_line(creds, tmp_path) -> None:
    offline = tmp_path / "offline"
    shutil.copytree(creds.root, offline)
    (offline / "ca-key.pem").unlink()
    one_line(cli("auth", "export", str(offline), "relay", "--host", "dash", "-o", str(tmp_path / "a")),
             f"error [config]: {offline / 'ca-key.pem'} is missing: exporting a relay signs")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    one_line(cli("auth", "export", str(creds.root), "relay", "--host", "dash", "-o", str(tmp_path / "full")),
             f"error [config]: {tmp_path / 'full'} is not empty")
    one_line(cli("auth", "export", str(tmp_path / "nothing"), "relay", "--host", "dash", "-o", str(tmp_path / "b")),
             "error [config]: ")
    one_line(cli("auth", "export", str(creds.root), "relay", "--host", "dash", "--listen", "tcp/0.0.0.0:7448",
                 "-o", str(tmp_path / "c")), "error [config]: --listen endpoint 'tcp/0.0.0.0:7448' must be tls/")


# --- malformed files: one line each ---------------------------------------------------------------------------

def _edit(path: Path, change) -> None:
    conf = read_json5(path)
    change(conf)
    write_json5(path, conf, "edited")


DAMAGES = {
    "relay.json5 not JSON": ("relay.json5", lambda p: p.write_text("{ not json"), "relay.json5: not a config"),
    "relay.json5 no hub": ("relay.json5", lambda p: _edit(p, lambda c: c.pop("connect")), "relay.json5: no connect"),
    "relay.json5 no password": ("relay.json5", lambda p: _edit(p, lambda c: c["transport"]["auth"]["usrpwd"].pop(
        "password")), "relay.json5: no transport/auth/usrpwd/password"),
    "relay.json5 bad key": ("relay.json5", lambda p: _edit(p, lambda c: c["transport"]["link"]["tls"].update(
        connect_private_key_base64="!!")), "relay.json5: transport/link/tls/connect_private_key_base64 is not"),
    "relay.json5 a list": ("relay.json5", lambda p: p.write_text("[1, 2]"), "relay.json5: not a config"),
    "passwords.txt malformed": ("passwords.txt", lambda p: p.write_text("monitor\n"), "passwords.txt: line 1"),
    "passwords.txt gone": ("passwords.txt", lambda p: p.unlink(), "passwords.txt: cannot read it"),
    "relay-cert.pem garbage": ("relay-cert.pem", lambda p: p.write_text("garbage"), "relay-cert.pem / relay-key"),
    "relay-key.pem garbage": ("relay-key.pem", lambda p: p.write_text("garbage"), "relay-cert.pem / relay-key"),
    "relay-key.pem gone": ("relay-key.pem", lambda p: p.unlink(), "relay-key.pem is missing"),
    "ca.pem garbage": ("ca.pem", lambda p: p.write_bytes(b"\x00\x01"), "ca.pem: not a usable CA certificate"),
}


@pytest.mark.parametrize("case", sorted(DAMAGES))
def test_a_malformed_file_of_the_relays_folder_is_one_line(folder, tmp_path, case) -> None:
    name, damage, says = DAMAGES[case]
    copy = tmp_path / "relay"
    shutil.copytree(folder.root, copy)
    damage(copy / name)
    line = one_line(cli("relay", "--secure", str(copy)), f"error [config]: {copy}/")
    assert says in line, line


def test_a_damaged_credentials_folder_is_one_line_too(creds, tmp_path) -> None:
    """The issue's case: a damaged operator.json5 crashed the relay with KeyError: 'connect'."""
    copy = tmp_path / "fabric"
    shutil.copytree(creds.root, copy)
    _edit(copy / "operator.json5", lambda c: c.pop("connect"))
    line = one_line(cli("relay", "--secure", str(copy), "--listen", f"tls/127.0.0.1:{free_port()}"),
                    f"error [config]: {copy / 'operator.json5'}: no connect/endpoints")
    assert "auth init" in line
    _edit(copy / "monitor.json5", lambda c: c["transport"].pop("auth"))
    one_line(cli("relay", "--secure", str(copy), "--listen", f"tls/127.0.0.1:{free_port()}", "--connect",
                 creds.hub_endpoints()[0]), f"error [config]: {copy / 'monitor.json5'}: no transport/auth")
    again = tmp_path / "again"
    shutil.copytree(creds.root, again)
    (again / "hub.json5").write_text("")
    one_line(cli("up", "--secure", str(again)), f"error [config]: {again / 'hub.json5'}: not a config")


# --- a relay at work ------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def secured(creds, tmp_path_factory):
    """A secured hub (in this process) and a supervisor joined with the services' config: the cell's read-only
    queries have someone to answer them."""
    cell = f"x{uuid.uuid4().hex[:8]}"
    with zenoh.open(hub_zenoh_config(creds, SessionSettings())), \
            zenoh.open(zenoh.Config.from_file(str(creds.config("service")))) as svc:
        supervisor = SupervisorService(svc, cell, tmp_path_factory.mktemp("sup"))
        supervisor.start()
        try:
            yield cell
        finally:
            supervisor.close()


def test_a_relay_runs_from_its_folder_alone(creds, folder, secured, tmp_path) -> None:
    """Copied elsewhere (another host's path), with nothing else: dashboards get the read-only queries through it;
    the operator's config is refused at the relay in one line that names it and says where commands go."""
    here = tmp_path / "etc" / "am-fabric-relay"
    shutil.copytree(folder.root, here)
    relay_ep = folder.listen_endpoints()[0]
    with relay_process("--secure", str(here)) as proc:
        assert proc.poll() is None
        dash = ["--config", str(here / "monitor.json5"), "--cell", secured]
        deadline = time.monotonic() + 30
        while (done := cli("job", "list", *dash, "--json")).returncode != 0 and time.monotonic() < deadline:
            time.sleep(0.5)                     # until the relay has learnt where the supervisor answers
        assert done.returncode == 0 and json.loads(done.stdout)["jobs"] == [], done.stderr
        one_line(cli("stop", *dash), "error [forbidden]: the monitor role may not run station/stop")
        line = one_line(cli("stop", "--config", str(creds.config("operator")), "--connect", relay_ep, "--cell",
                            secured), f"error [forbidden]: the relay at {relay_ep} refused this session: a relay "
                                      f"admits dashboards with the monitor's config only")
        assert creds.hub_endpoints()[0] in line       # where commands go


def test_a_relay_of_the_whole_folder_refuses_commands_as_forbidden_and_names_itself(creds, secured) -> None:
    """Run from the credentials folder the relay admits the operator's config, with a monitor's rights: a command
    is refused at once, [forbidden], naming the relay (not 'no station/stop on the fabric ... is the service
    running'); a query that finds no one names the relay too."""
    ep = f"tls/127.0.0.1:{free_port()}"
    op = ["--config", str(creds.config("operator")), "--connect", ep]
    with relay_process("--secure", str(creds.root), "--listen", ep):
        deadline = time.monotonic() + 30
        while cli("job", "list", *op, "--cell", secured).returncode != 0 and time.monotonic() < deadline:
            time.sleep(0.5)
        t0 = time.monotonic()
        line = one_line(cli("stop", *op, "--cell", secured),
                        f"error [forbidden]: the relay at {ep} may not pass station/stop: a relay gives every "
                        f"session a monitor's rights")
        assert time.monotonic() - t0 < 10 and "operator" in line and creds.hub_endpoints()[0] in line
        line = one_line(cli("position", *op, "--cell", "nosuchcell"), "error [unavailable]: no station/position")
        assert f"through the relay at {ep}" in line
