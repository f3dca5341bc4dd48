"""The base install (no extra) is enough for fabric-cli against a running cell and for a plain monitor; a command
that needs an extra says so in one line.

The base install is stood in for by a Python in which the extras' packages cannot be imported (a meta-path finder
raises ModuleNotFoundError for them), run against the real cell's processes; it also records which third-party
packages each command imported, and those must all come from ``[project] dependencies``."""
from __future__ import annotations

import ast
import csv
import importlib.metadata
import json
import os
import re
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from fabric.extras import EXTRAS, extra_of

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib

pytestmark = pytest.mark.timeout(300)

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())

# What the extras bring (and what they bring in turn: coal's and Pinocchio's bindings, Textual's rich, pillow).
BLOCKED = ("pinocchio", "coal", "hppfcl", "eigenpy", "example_robot_data", "trimesh", "shapely", "manifold3d",
           "mapbox_earcut", "scipy", "ruckig", "networkx", "textual", "rich", "matplotlib", "mpl_toolkits",
           "pyarrow", "PIL", "tomli")

# Runs module (or script) ARGV[1] with the rest as its arguments, the BLOCKED packages unimportable; at exit
# writes the top-level third-party modules it imported (not fabric) to $IMPORT_TRACE.
WRAPPER = r"""
import atexit, json, os, runpy, sys
BLOCKED = set(os.environ["BLOCKED_MODULES"].split(","))

class Blocker:
    def find_spec(self, fullname, path=None, target=None):
        if fullname.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {fullname!r} (blocked by the test)", name=fullname)
        return None

before = set(sys.modules)
sys.meta_path.insert(0, Blocker())

def trace():
    tops = {m.split(".")[0] for m in set(sys.modules) - before} - set(sys.stdlib_module_names)
    with open(os.environ["IMPORT_TRACE"], "w") as f:
        json.dump(sorted(t for t in tops if not t.startswith("_") and t != "fabric"), f)

atexit.register(trace)
target = sys.argv[1]
sys.argv = sys.argv[1:]
if target.endswith(".py"):
    runpy.run_path(target, run_name="__main__")
else:
    runpy.run_module(target, run_name="__main__", alter_sys=True)
"""

# A monitor that knows nothing of this project: zenoh and msgpack, the keys and payloads of docs/protocol.md.
MONITOR = r"""
import json, sys, threading
import msgpack, zenoh

endpoints, cell, want = json.loads(sys.argv[1]), sys.argv[2], int(sys.argv[3])
conf = zenoh.Config()
conf.insert_json5("mode", json.dumps("client"))
conf.insert_json5("connect/endpoints", json.dumps(endpoints))
conf.insert_json5("scouting/multicast/enabled", "false")
got, done = [], threading.Event()

def on_pose(sample):
    got.append(msgpack.unpackb(sample.payload.to_bytes()))
    if len(got) >= want:
        done.set()

with zenoh.open(conf) as session:
    sub = session.declare_subscriber(f"am/{cell}/station/pose", on_pose)
    done.wait(60)
    sub.undeclare()
print(json.dumps(got[:want]))
"""


def _canon(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _requirement_name(req: str) -> str:
    return _canon(re.match(r"[A-Za-z0-9._-]+", req.strip()).group(0))


def _modules_of(dists: list[str]) -> set[str]:
    """The top-level modules the installed distributions ``dists`` provide."""
    wanted = {_canon(d) for d in dists}
    mods = {m for m, ds in importlib.metadata.packages_distributions().items() if wanted & {_canon(d) for d in ds}}
    return mods | {d.replace("-", "_") for d in wanted}


BASE_DISTS = [_requirement_name(r) for r in PYPROJECT["project"]["dependencies"]]
BASE_MODULES = _modules_of(BASE_DISTS)


def blocked_run(target: str, *args: str, trace: Path, block: tuple[str, ...] = BLOCKED,
                timeout: float = 120) -> tuple[subprocess.CompletedProcess, list[str]]:
    env = dict(os.environ, BLOCKED_MODULES=",".join(block), IMPORT_TRACE=str(trace))
    r = subprocess.run([sys.executable, "-c", WRAPPER, target, *args], capture_output=True, text=True,
                       timeout=timeout, env=env, cwd=trace.parent)
    imported = json.loads(trace.read_text()) if trace.exists() else []
    return r, imported


@pytest.fixture(scope="module")
def cell_args(running_cell) -> list[str]:
    return replace(running_cell.settings, mode="client").to_args()


@pytest.fixture
def base_cli(cell_args, tmp_path):
    """``fabric-cli ARGS`` against the cell in the blocked Python: its result and the third-party packages it
    imported (which the base install must bring)."""
    n = iter(range(1000))

    def run(*args: str, against_cell: bool = True) -> tuple[subprocess.CompletedProcess, list[str]]:
        return blocked_run("fabric.cli.main", *args, *(cell_args if against_cell else []),
                           trace=tmp_path / f"trace-{next(n)}.json")
    return run


def _assert_base(imported: list[str], what: str) -> None:
    assert "zenoh" in imported and "msgpack" in imported, (what, imported)
    outside = sorted(set(imported) - BASE_MODULES - {"cmeel_pth", "cython_runtime"})
    assert not outside, f"{what} imported {outside}, which the base dependencies {BASE_DISTS} do not bring"


def test_client_commands_work_without_the_extras(base_cli):
    r, imported = base_cli("status", "--json", "--wait", "60")
    assert r.returncode == 0, r.stderr
    status = json.loads(r.stdout)
    assert all(svc["alive"] for svc in status["services"]) and len(status["services"]) == 5
    _assert_base(imported, "status")

    r, imported = base_cli("position", "--json")
    assert r.returncode == 0, r.stderr
    pose = json.loads(r.stdout)
    assert len(pose["xyz_mm"]) == 3 and len(pose["q_deg"]) == 6
    _assert_base(imported, "position")

    r, imported = base_cli("state")
    assert r.returncode == 0 and "state:" in r.stdout, r.stderr
    _assert_base(imported, "state")

    r, imported = base_cli("job", "list", "--json")
    assert r.returncode == 0, r.stderr
    assert isinstance(json.loads(r.stdout)["jobs"], list)
    _assert_base(imported, "job list")

    r, imported = base_cli("events", "--json")
    assert r.returncode == 0, r.stderr
    assert "events" in json.loads(r.stdout)
    _assert_base(imported, "events")

    r, imported = base_cli("watch", "pose", "--count", "3", "--timeout", "30", "--json")
    assert r.returncode == 0, r.stderr
    poses = [json.loads(line) for line in r.stdout.splitlines()]
    assert len(poses) == 3 and all(len(p["xyz_mm"]) == 3 for p in poses)
    assert poses[0]["seq"] < poses[1]["seq"] < poses[2]["seq"]
    _assert_base(imported, "watch pose")


def test_record_to_csv_works_without_the_extras_and_parquet_says_which_extra(base_cli, tmp_path):
    out = tmp_path / "pose.csv"
    r, imported = base_cli("record", "pose", "-o", str(out), "--duration", "1")
    assert r.returncode == 0, r.stderr
    with open(out, newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows and rows[0]["topic"] == "pose"
    _assert_base(imported, "record to CSV")
    r, _ = base_cli("record", "pose", "-o", str(tmp_path / "pose.parquet"), "--duration", "1")
    _assert_one_line(r, "fabric-cli record needs the record extra (pyarrow is not installed): "
                        "pip install 'am-fabric[record]'")


def _assert_one_line(r: subprocess.CompletedProcess, message: str, code: int = 1) -> None:
    assert r.returncode == code, (r.stdout, r.stderr)
    assert "Traceback" not in r.stderr and r.stderr.strip().count("\n") == 0, r.stderr
    assert r.stderr.strip().endswith(message), r.stderr


def test_commands_that_need_an_extra_say_so_in_one_line(base_cli, tmp_path):
    r, _ = base_cli("up", "--connect", "tcp/127.0.0.1:9", "--cell", "never", against_cell=False)
    _assert_one_line(r, "error [config]: fabric-cli up needs the services extra (pinocchio is not installed): "
                        "pip install 'am-fabric[services]'")
    r, _ = base_cli("serve", "station", against_cell=False)      # which module it meets first: import order
    _assert_one_line(r, "pip install 'am-fabric[services]'")
    assert re.search(r"fabric-cli serve station needs the services extra \((pinocchio|ruckig|trimesh|scipy|coal) "
                     r"is not installed\)", r.stderr), r.stderr
    r, _ = base_cli("cell", "show", against_cell=False)
    _assert_one_line(r, "fabric-cli cell show needs the services extra (pinocchio is not installed): "
                        "pip install 'am-fabric[services]'")
    recording = tmp_path / "run.csv"
    recording.write_text("topic,rx_seq,seq,t_sim_s,wall_s\npose,1,1,0.0,0.0\n")
    r, _ = base_cli("plot", str(recording), "-o", str(tmp_path / "run.png"), against_cell=False)
    _assert_one_line(r, "error [config]: fabric-cli plot needs the record extra (matplotlib is not installed): "
                        "pip install 'am-fabric[record]'")
    r, _ = base_cli("plot", str(recording), "-o", str(tmp_path / "run.png"), "--json", against_cell=False)
    assert r.returncode == 1 and json.loads(r.stdout)["error"]["details"] == {
        "field": "extras", "value": "record", "module": "matplotlib"}
    r, _ = blocked_run("fabric.tui", "--connect", "tcp/127.0.0.1:9", trace=tmp_path / "tui.json")
    _assert_one_line(r, "fabric-tui: error [config]: the console needs the tui extra (textual is not installed): "
                        "pip install 'am-fabric[tui]'", code=2)


def test_the_console_needs_only_textual_besides_the_base(tmp_path):
    """With the tui extra and no other, the console's modules import (the cell model's joint limits, which need
    Pinocchio, are then reported as unknown in the console)."""
    script = tmp_path / "console.py"
    script.write_text("import fabric.tui.app\n")
    block = tuple(m for m in BLOCKED if extra_of(m) != "tui")
    r, imported = blocked_run(str(script), trace=tmp_path / "trace.json", block=block)
    assert r.returncode == 0, r.stderr
    assert "textual" in imported and not set(imported) & set(block)


def test_a_plain_monitor_gets_pose_with_zenoh_and_msgpack_only(running_cell, tmp_path):
    """No fabric module either: the monitor is blocked from importing this project at all."""
    script = tmp_path / "monitor.py"
    script.write_text(MONITOR)
    r, imported = blocked_run(str(script), json.dumps(running_cell.settings.connect), running_cell.settings.cell, "5",
                              trace=tmp_path / "trace.json", block=(*BLOCKED, "fabric"))
    assert r.returncode == 0, r.stderr
    poses = json.loads(r.stdout)
    assert len(poses) == 5
    assert all(p["_t"] == "station.Pose" and len(p["xyz_mm"]) == 3 and len(p["q_deg"]) == 6 for p in poses)
    assert set(imported) <= {"zenoh", "msgpack", "cmeel_pth", "cython_runtime"}, imported


# --- static: the dependency lists ------------------------------------------------------------------------------

CLIENT_SIDE = ("fabric/wire", "fabric/schemas", "fabric/client", "fabric/cli", "fabric/security", "fabric/extras.py")


def _module_path(name: str) -> Path | None:
    base = ROOT / Path(*name.split("."))
    for p in (base.with_suffix(".py"), base / "__init__.py"):
        if p.is_file():
            return p
    return None


def _imports(path: Path, module_level_only: bool) -> set[str]:
    """The modules ``path`` imports (``from a import b`` counts ``a`` and, where it is a module, ``a.b``);
    never those under ``if TYPE_CHECKING:``, and with ``module_level_only`` not those inside functions."""
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        if module_level_only and isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            return
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f"{node.module}.{a.name}" for a in node.names if _module_path(f"{node.module}.{a.name}"))
        for child in ast.iter_child_nodes(node):
            visit(child)
    visit(ast.parse(path.read_text()))
    return found


def _third_party(names: set[str]) -> set[str]:
    return {n.split(".")[0] for n in names} - set(sys.stdlib_module_names) - {"fabric", "__future__"}


def test_base_dependencies_cover_what_the_client_side_imports():
    """Everything under wire, schemas, client, cli and security, and what it imports at module level, needs only
    the base dependencies (the lazy imports of the client commands are covered by the blocked runs above)."""
    todo = [p for entry in CLIENT_SIDE for p in ([ROOT / entry] if entry.endswith(".py")
                                                 else sorted((ROOT / entry).rglob("*.py")))]
    seen: set[Path] = set()
    third: dict[str, set[str]] = {}
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        names = _imports(path, module_level_only=True)
        for top in _third_party(names):
            third.setdefault(top, set()).add(str(path.relative_to(ROOT)))
        for name in names:
            parts = name.split(".")
            if parts[0] == "fabric":   # importing fabric.a.b runs fabric/__init__ and fabric/a/__init__ too
                todo += [p for i in range(1, len(parts) + 1) if (p := _module_path(".".join(parts[:i])))]
    assert "zenoh" in third and "msgpack" in third
    tomli_only_on_310 = {"tomli"} if sys.version_info >= (3, 11) else set()
    outside = {m: sorted(w) for m, w in third.items() if m not in BASE_MODULES | tomli_only_on_310}
    assert not outside, f"imported on the client side but not in the base dependencies {BASE_DISTS}: {outside}"


def test_extras_in_pyproject_match_fabric_extras_and_cover_every_import():
    extras = PYPROJECT["project"]["optional-dependencies"]
    assert extras["all"] == ["am-fabric[services,tui,record]"]
    for extra, dists in EXTRAS.items():
        listed = {_requirement_name(r) for r in extras[extra] if ";" not in r}
        assert listed == {_canon(d) for d in dists}, extra
    assert {_requirement_name(r) for r in extras["services"] if ";" in r} == {"tomli"}
    assert not set(BASE_DISTS) & {_canon(d) for dists in EXTRAS.values() for d in dists}
    third: dict[str, set[str]] = {}
    for path in sorted((ROOT / "fabric").rglob("*.py")):
        for top in _third_party(_imports(path, module_level_only=False)):
            third.setdefault(top, set()).add(str(path.relative_to(ROOT)))
    undeclared = {m: sorted(w) for m, w in third.items() if m not in BASE_MODULES and extra_of(m) is None}
    assert not undeclared, f"imported by fabric/ but in no dependency list: {undeclared}"
