"""The rule that sorts tests into tiers, and the guard that proves the fast tier opens no session and starts no
fabric process (support/tiers.py; ``tools/test --fast``)."""
from __future__ import annotations

import sys

import pytest
import zenoh

import support.tiers as tiers
from support.tiers import FastTierGuard, FastTierViolation, is_fabric_process, module_reasons

SOURCES = {
    "pure": "import numpy as np\nfrom fabric.wire.memory import MemoryFabric\n\ndef test_x():\n    assert np.ones(1)\n",
    "processes": "import subprocess\n",
    "sessions": "import zenoh\n\ndef test_x():\n    zenoh.open(zenoh.Config())\n",
    "client": "from fabric.client import Client\n\ndef f(st):\n    return Client.connect(st)\n",
    "cell": "from fabric.cli.up import CellProcesses\n",
    "helpers": "from support.loopback import free_port\n",
}


def test_a_modules_source_says_whether_it_opens_sessions_or_starts_processes(tmp_path):
    found = {}
    for name, source in SOURCES.items():
        path = tmp_path / f"test_{name}.py"
        path.write_text(source)
        found[name] = module_reasons(str(path))
    assert found["pure"] == ()
    assert found["processes"] == ("starts processes (imports subprocess)",)
    assert found["sessions"] == ("opens a Zenoh session (zenoh.open)",)
    assert found["client"] == ("opens a Zenoh session (Client.connect)",)
    assert found["cell"] == ("starts the cell's processes (CellProcesses)",)
    assert found["helpers"] == ("uses the slow tier's helpers (support.loopback)",)


def test_fabric_processes_are_told_from_other_programs():
    assert is_fabric_process([sys.executable, "-m", "fabric.cli.main", "up"])
    assert is_fabric_process(["fabric-cli", "status"]) and is_fabric_process("python3 -c pass")
    assert not is_fabric_process(["prusa-slicer", "--version"]) and not is_fabric_process(["cc", "-O2", "x.c"])


def test_the_guard_refuses_sessions_and_fabric_processes_and_remembers_each(request):
    guard, patch = FastTierGuard(), pytest.MonkeyPatch()
    guard.install(patch)
    try:
        # reached through the tiers module: a direct zenoh.open here would put this module in the slow tier
        with pytest.raises(FastTierViolation, match="opened a Zenoh session"):
            tiers.zenoh.open(zenoh.Config())
        with pytest.raises(FastTierViolation, match="started a fabric process"):
            tiers.subprocess.Popen([sys.executable, "-c", "pass"])
    finally:
        patch.undo()
    assert len(guard.take()) == 2 and guard.take() == []
    assert request.node.get_closest_marker("fast") is not None        # this module is in the fast tier
