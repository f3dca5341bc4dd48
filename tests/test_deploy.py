"""The deployment guide (deploy/README.md) and its systemd units, as a newcomer runs them.

Without root: every ``FABRIC_*`` variable the code reads is in the guide's table, once, and nothing else is;
every file in deploy/ is the guide's; the units are secure by default. With root and network namespaces: the
guide's two walk-throughs run line by line on two "hosts" (``hub.example`` and ``dash.example``, each its own
network namespace, its own /etc and /var/lib and home folder): the open one (``up`` on the hub's host, the CLI
and a relay on the dashboards'), then the secured one, where ``systemctl enable --now UNIT`` runs each unit's
``ExecStart=`` (parsed from the file, ``Environment=`` and ``%i`` substituted) and the relay's host holds only
the folder ``auth export`` made for it. A line followed by ``error [code]: ...`` must fail with that line.
"""
from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from fabric.demo import sample_model

from test_multihost import ADDR_A, ADDR_B, hosts  # noqa: F401  (the fixture)

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "deploy" / "README.md"
UNITS = ROOT / "deploy" / "systemd"
NAMES = {"hub": "hub.example", "dash": "dash.example"}
FABRIC_CLI = ("fabric-cli", "/opt/am-fabric/.venv/bin/fabric-cli")
_VAR = re.compile(r"\bFABRIC_[A-Z][A-Z0-9_]*\b")

needs_netns = pytest.mark.skipif(os.geteuid() != 0 or shutil.which("ip") is None,
                                 reason="needs root and iproute2 for network namespaces")


# --- reading the guide and the units ------------------------------------------------------------------------

@dataclass
class Step:
    host: str
    argv: list[str]
    background: bool = False
    expect: list[str] = field(default_factory=list)

    def __str__(self) -> str:
        return f"{self.host}$ {shlex.join(self.argv)}{' &' if self.background else ''}"


def walkthrough(name: str) -> list[Step]:
    """The steps of the guide's block ```` ```sh walk-through:<name> ````: ``host$ command`` lines (``&``: left
    running), each followed by the lines it must print (an ``error [code]: ...`` line: it must fail so)."""
    text = GUIDE.read_text()
    m = re.search(rf"^```sh walk-through:{re.escape(name)}\n(.*?)^```", text, re.S | re.M)
    assert m, f"no walk-through:{name} block in {GUIDE}"
    steps: list[Step] = []
    for line in m.group(1).splitlines():
        prompt = re.match(r"^(\w+)\$\s+(.*)$", line)
        if prompt:
            assert prompt.group(1) in NAMES, line
            cmd = prompt.group(2).strip()
            background = cmd.endswith("&")
            steps.append(Step(prompt.group(1), shlex.split(cmd.rstrip("&").strip()), background))
        elif line.strip():
            assert steps, f"output before any command: {line}"
            steps[-1].expect.append(line.strip())
    return steps


def unit(name: str) -> tuple[dict[str, str], list[str], dict[str, list[str]]]:
    """A unit's ``Environment=``, its ``ExecStart=`` (``%i`` and ``${VAR}`` substituted) and all its settings."""
    base, _, instance = name.partition("@")
    path = UNITS / (f"{base}@.service" if instance else f"{name}.service")
    settings: dict[str, list[str]] = {}
    for line in path.read_text().splitlines():
        if "=" in line and not line.lstrip().startswith(("#", ";", "[")):
            key, _, value = line.partition("=")
            settings.setdefault(key.strip(), []).append(value.strip())
    env = dict(v.partition("=")[::2] for v in settings.get("Environment", []))
    (exec_start,) = settings["ExecStart"]
    exec_start = exec_start.replace("%i", instance)
    exec_start = re.sub(r"\$\{(\w+)\}|\$(\w+)", lambda m: env[m.group(1) or m.group(2)], exec_start)
    return env, shlex.split(exec_start), settings


def unit_files() -> list[str]:
    return sorted(p.name for p in UNITS.glob("*.service"))


# --- without root --------------------------------------------------------------------------------------------

def test_every_fabric_variable_is_in_the_guide_once_with_one_meaning():
    in_code = set()
    for path in (ROOT / "fabric").rglob("*.py"):
        in_code |= set(_VAR.findall(path.read_text()))
    rows = [ln for ln in GUIDE.read_text().splitlines() if ln.startswith("| `FABRIC_")]
    listed = [name for row in rows for name in _VAR.findall(row.split("|")[1])]
    assert sorted(listed) == sorted(set(listed)), "a variable is listed twice"
    assert set(listed) == in_code, f"code reads {sorted(in_code)}, the guide lists {sorted(listed)}"
    mentioned = set(_VAR.findall(GUIDE.read_text()))
    for name in unit_files():
        mentioned |= set(_VAR.findall((UNITS / name).read_text()))
    assert mentioned <= in_code, f"deploy/ names variables the code never reads: {sorted(mentioned - in_code)}"
    for name in unit_files():
        env, _, _ = unit(name.replace("@.service", "@x").removesuffix(".service"))
        assert "FABRIC_HUB" not in env, f"{name}: the hub's address comes from the role's config"


def test_every_file_in_deploy_is_the_guides():
    guide = GUIDE.read_text()
    files = [p for p in (ROOT / "deploy").rglob("*") if p.is_file() and p != GUIDE]
    assert files, "no unit?"
    for path in files:
        assert path.suffix == ".service", f"{path}: a file the guide does not use"
        assert f"systemd/{path.name}" in guide, f"{path.name} is not in the guide"
    run = {u.partition("@")[0] + ("@" if "@" in u else "") for s in walkthrough("secured")
           if s.argv[:3] == ["systemctl", "enable", "--now"] for u in s.argv[3:]}
    assert {f.removesuffix(".service") for f in unit_files()} == run, "a unit the walk-through does not run"


def test_units_are_secure_by_default():
    for name in unit_files():
        env, argv, settings = unit(name.replace("@.service", "@station").removesuffix(".service"))
        assert settings.get("User") == ["am-fabric"], f"{name}: runs as root"
        assert argv[0] == "/opt/am-fabric/.venv/bin/fabric-cli", name
        assert not any(a.startswith("tcp/") for a in argv), f"{name}: an open endpoint"
        assert "--secure" in argv or "--config" in argv, f"{name}: no credentials"
        assert settings.get("NoNewPrivileges") == ["yes"] and settings.get("ProtectSystem") == ["strict"], name
    env, argv, settings = unit("am-fabric@station")
    assert argv[argv.index("--config") + 1] == "/etc/am-fabric/service.json5"
    assert argv[argv.index("--data-dir") + 1] == env["FABRIC_DATA_DIR"] == "/var/lib/am-fabric"
    assert settings["StateDirectory"] == ["am-fabric"] and settings["RestartPreventExitStatus"] == ["78"]
    assert "--listen" not in argv, "on a secured fabric services listen nowhere"
    assert unit("am-fabric-hub")[1][1:] == ["router", "--secure", "/etc/am-fabric"]
    assert unit("am-fabric-relay")[1][1:] == ["relay", "--secure", "/etc/am-fabric-relay"]


def test_the_walkthroughs_parse():
    for name in ("open", "secured"):
        steps = walkthrough(name)
        assert {s.host for s in steps} == set(NAMES)
        for s in steps:
            assert s.argv[0] in (*FABRIC_CLI, "export", "scp", "chown", "sudo", "systemctl"), str(s)
            assert not s.expect or s.expect[0].startswith("error ["), f"{s}: only errors are checked"


# --- two hosts -----------------------------------------------------------------------------------------------

class Host:
    """One "host": a network namespace, its own /etc, /var/lib and home (its working folder), its shell's
    environment, and what it left running."""

    def __init__(self, name: str, ns: str, root: Path) -> None:
        self.name, self.ns, self.root = name, ns, root
        self.home = root / "home"
        self.home.mkdir(parents=True)
        self.env = {k: v for k, v in os.environ.items() if not k.startswith(("FABRIC_", "XDG_"))}
        self.env.update(HOME=str(self.home), PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
        self.procs: list[tuple[str, subprocess.Popen, Path]] = []

    def path(self, arg: str) -> str:
        """An absolute /etc, /var or /opt path is this host's own."""
        return str(self.root) + arg if arg.startswith(("/etc/", "/var/")) or arg in ("/etc", "/var") else arg

    def where(self, spec: str, machines: dict[str, Host]) -> Path:
        """``host.example:PATH`` (scp) or a path of this host."""
        for h in machines.values():
            if spec.startswith(NAMES[h.name] + ":"):
                p = spec.split(":", 1)[1]
                return Path(h.path(p)) if p.startswith("/") else h.home / p
        return Path(self.path(spec)) if spec.startswith("/") else self.home / spec

    def command(self, argv: list[str], env: dict[str, str] | None = None) -> tuple[list[str], dict[str, str]]:
        assert argv[0] in FABRIC_CLI, argv
        full = ["ip", "netns", "exec", self.ns, sys.executable, "-m", "fabric.cli.main",
                *(self.path(a) for a in argv[1:])]
        return full, {**self.env, **{k: self.path(v) for k, v in (env or {}).items()}}

    def start(self, what: str, argv: list[str], env: dict[str, str] | None = None) -> None:
        cmd, env = self.command(argv, env)
        log = self.root / f"{len(self.procs)}-{re.sub(r'[^a-z0-9@-]+', '_', what)}.log"
        with open(log, "wb") as out:
            self.procs.append((what, subprocess.Popen(cmd, cwd=self.home, env=env, stdout=out,
                                                      stderr=subprocess.STDOUT), log))

    def logs(self) -> str:
        out = []
        for what, proc, log in self.procs:
            tail = log.read_text(errors="replace")[-1500:] if log.exists() else ""
            out.append(f"--- {self.name}: {what} ({'running' if proc.poll() is None else proc.poll()})\n{tail}")
        return "\n".join(out)

    def stop(self) -> None:
        for _, proc, _ in self.procs:
            if proc.poll() is None:
                proc.terminate()
        for _, proc, _ in self.procs:
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


@pytest.fixture
def two_hosts(hosts, tmp_path):  # noqa: F811
    """hub.example and dash.example: two namespaces joined by a veth link, each naming the other."""
    a, b, _ = hosts
    etc = [Path("/etc/netns") / ns for ns in (a, b)]
    try:
        for d in etc:                           # `ip netns exec` mounts these over /etc/hosts
            d.mkdir(parents=True, exist_ok=True)
            (d / "hosts").write_text(f"127.0.0.1 localhost\n::1 localhost\n{ADDR_A} hub.example\n"
                                     f"{ADDR_B} dash.example\n")
        found = {"hub": Host("hub", a, tmp_path / "hub"), "dash": Host("dash", b, tmp_path / "dash")}
        shutil.copyfile(sample_model(), found["dash"].home / "part.stl")
        try:
            yield found
        finally:
            for h in found.values():
                h.stop()
    finally:
        for d in etc:
            shutil.rmtree(d, ignore_errors=True)


def run_walkthrough(name: str, machines: dict[str, Host]) -> list[str]:
    """Run the guide's walk-through ``name``; the units it started."""
    started: list[str] = []
    for step in walkthrough(name):
        host = machines[step.host]
        argv = step.argv
        if argv[:2] == ["sudo", "-u"]:
            argv = argv[3:]                      # the test runs everything as root
        if argv[0] == "export":
            key, _, value = argv[1].partition("=")
            host.env[key] = host.path(value)
        elif argv[0] == "chown":
            continue                             # no am-fabric user here
        elif argv[0] == "scp":
            src, dst = (host.where(x, machines) for x in argv[-2:])
            if dst.is_dir():
                dst = dst / src.name
            dst.parent.mkdir(parents=True, exist_ok=True)
            if src.is_dir():
                shutil.copytree(src, dst)
            else:
                shutil.copy2(src, dst)
        elif argv[:3] == ["systemctl", "enable", "--now"]:
            for name_ in argv[3:]:
                env, exec_argv, _ = unit(name_)
                host.start(name_, exec_argv, env)
                started.append(name_)
        elif step.background:
            host.start(argv[1], argv)
        else:
            cmd, env = host.command(argv)
            done = subprocess.run(cmd, cwd=host.home, env=env, capture_output=True, text=True, timeout=240)
            said = (done.stdout + done.stderr).strip()
            why = f"{step}\n{said}\n\n{machines['hub'].logs()}\n{machines['dash'].logs()}"
            if step.expect:
                assert done.returncode != 0, why
                want = step.expect[0].removesuffix("...").strip()
                assert done.stderr.strip().splitlines() == [done.stderr.strip()], f"not one line: {why}"
                assert done.stderr.strip().startswith(want), f"expected {want!r}: {why}"
                assert "Traceback" not in said
            else:
                assert done.returncode == 0, why
    return started


@needs_netns
@pytest.mark.timeout(420)
def test_the_open_walkthrough_runs_from_the_guide(two_hosts):
    run_walkthrough("open", two_hosts)


@needs_netns
@pytest.mark.timeout(420)
def test_the_secured_walkthrough_runs_the_units_and_a_relay_with_only_its_folder(two_hosts):
    started = run_walkthrough("secured", two_hosts)
    assert {u.partition("@")[0] for u in started} == {f.removesuffix(".service").partition("@")[0]
                                                       for f in unit_files()}
    hub, dash = two_hosts["hub"], two_hosts["dash"]
    for what, proc, _ in hub.procs + dash.procs:
        assert proc.poll() is None, f"{what} exited\n{hub.logs()}\n{dash.logs()}"
    # the dashboards' host holds the relay's folder, the operator's config it was handed, and the part
    from fabric.security.credentials import Credentials
    from fabric.security.relay import RelayFolder
    relay = dash.root / "etc" / "am-fabric-relay"
    assert sorted(p.name for p in relay.iterdir()) == sorted(RelayFolder.FILES)
    held = sorted(str(p.relative_to(dash.root)) for p in dash.root.rglob("*") if p.is_file()
                  and p.suffix != ".log" and not p.is_relative_to(relay))
    assert held == ["home/operator.json5", "home/part.stl"], held
    secrets = Credentials(hub.root / "etc" / "am-fabric").read_passwords()
    for path in relay.iterdir():
        text = path.read_bytes()
        for role in ("operator", "service"):
            assert secrets[role].encode() not in text, f"{path.name} holds the {role}'s password"
    # the services kept their state where the unit says
    assert sorted(p.name for p in (hub.root / "var" / "lib" / "am-fabric" / "cell1").iterdir()) == sorted(
        ("station", "slicer", "planner", "collision", "supervisor"))
