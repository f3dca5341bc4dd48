"""Shared fixtures, and the tiers of the suite.

Fixtures: Zenoh sessions on free loopback ports (scouting off), the whole cell as processes (the slow tier),
and the in-process memory fabric (the fast tier). The helpers the tests import are in ``tests/support``.

Tiers (``support.tiers``): every test is marked ``fast`` unless it uses real sessions or processes, or is
marked ``slow`` or ``slicers``; ``pytest --fast`` (``tools/test --fast``) runs only those, with ``zenoh.open``
and fabric processes refused. ``pytest --fast --collect-only -v`` (one process) says why each module left out is.
"""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest
import zenoh

from fabric.cli.up import CellProcesses, hub_settings
from fabric.client import wait_connected
from fabric.wire.config import DATA_ROOT_ENV, SessionSettings, zenoh_config
from fabric.wire.memory import MemoryFabric

from support.loopback import free_port, make_settings
from support.tiers import FastTierGuard, module_reasons, slow_reasons

SLOW_MODULES = pytest.StashKey[set]()      # with --fast: the modules with tests left to the slow tier
FAST_TIMEOUT_S = 30.0                      # the slowest fast test takes 3 s on two busy cores


def pytest_addoption(parser) -> None:
    parser.addoption("--fast", action="store_true",
                     help="run only the fast tier: no real Zenoh session, no fabric process (support/tiers.py)")
    parser.addoption("--alone", action="store_true",
                     help="run only the tests marked alone (they need the machine to themselves: tools/test runs "
                          "them after the rest; a run with workers leaves them out)")


def pytest_configure(config) -> None:
    """Services started by tests keep their durable state in a folder of this run, never in the user's
    data folder (subprocesses inherit the variable)."""
    root = tempfile.mkdtemp(prefix="am-fabric-tests-")
    os.environ[DATA_ROOT_ENV] = root
    config._fabric_data_root = root


def pytest_unconfigure(config) -> None:
    shutil.rmtree(getattr(config, "_fabric_data_root", ""), ignore_errors=True)


def pytest_ignore_collect(collection_path, config):
    """With ``--fast``, a test module whose own source opens sessions or starts processes is not even imported."""
    if not config.getoption("fast") or not collection_path.name.startswith("test_") or collection_path.suffix != ".py":
        return None
    if module_reasons(str(collection_path)):
        config.stash.setdefault(SLOW_MODULES, set()).add(str(collection_path))
        return True
    return None


def pytest_collection_modifyitems(config, items) -> None:
    """Mark the fast tier; with ``--fast``, deselect the rest, and give each fast test FAST_TIMEOUT_S at most (its
    own timeout marker set aside: a fast test that hangs costs the tier that much, not two minutes)."""
    fast = config.getoption("fast")
    alone_only = config.getoption("alone")
    with_workers = bool(getattr(config.option, "numprocesses", None)) or hasattr(config, "workerinput")
    if alone_only or with_workers:            # a robot simulated at 1 kHz in real time needs the cores to itself
        keep = [item for item in items if bool(item.get_closest_marker("alone")) == alone_only]
        config.hook.pytest_deselected(items=[item for item in items if item not in keep])
        items[:] = keep
    slow = [item for item in items if slow_reasons(item)]
    slow_ids = {id(item) for item in slow}
    for item in items:
        if id(item) not in slow_ids:
            item.add_marker(pytest.mark.fast)
            if fast:
                item.add_marker(pytest.mark.timeout(FAST_TIMEOUT_S), append=False)
    if fast and slow:
        config.hook.pytest_deselected(items=slow)
        items[:] = [item for item in items if item.get_closest_marker("fast")]
        config.stash.setdefault(SLOW_MODULES, set()).update(str(item.path) for item in slow)


def pytest_terminal_summary(terminalreporter, config) -> None:
    """With ``--fast -v``: the modules with tests in the slow tier, and why (their own source's reasons; else
    some of their tests use real-session fixtures or are marked slow)."""
    modules = sorted(config.stash.get(SLOW_MODULES, set()))
    if not modules or config.getoption("verbose") < 1:
        return
    terminalreporter.section("kept for the slow tier")
    for path in modules:
        reasons = module_reasons(path)
        terminalreporter.write_line(f"{Path(path).name}: {'; '.join(reasons) or 'fixtures or the slow marker'}")


@pytest.fixture(scope="session", autouse=True)
def fast_tier_guard(request):
    """Under ``--fast``: ``zenoh.open`` and fabric processes refused for the whole run (support/tiers.py)."""
    if not request.config.getoption("fast"):
        yield None
        return
    guard, patch = FastTierGuard(), pytest.MonkeyPatch()
    guard.install(patch)
    yield guard
    patch.undo()


@pytest.fixture(autouse=True)
def _fast_tier_check(request, fast_tier_guard):
    """A fast-tier test that tried a session or a process (its fixtures included) fails, even if the code
    under test caught the error."""
    yield
    attempts = fast_tier_guard.take() if fast_tier_guard is not None else []
    if attempts:
        pytest.fail(f"{request.node.nodeid} is in the fast tier but {'; '.join(attempts)}", pytrace=False)


@pytest.fixture
def memory_fabric():
    """An in-process stand-in for the Zenoh transport (fabric.wire.memory): take sessions with ``.session()``."""
    with MemoryFabric() as fabric:
        yield fabric
        assert not fabric.callback_errors, f"callbacks raised: {fabric.callback_errors}"


@pytest.fixture
def settings() -> SessionSettings:
    """Fresh hub endpoint and cell name per test."""
    return make_settings()


@pytest.fixture
def hub(settings):
    """An in-process router session hosting the hub endpoint."""
    with zenoh.open(zenoh_config(hub_settings(settings))) as session:
        yield session


@pytest.fixture
def session(hub, settings):
    """A peer session connected to the hub."""
    with zenoh.open(zenoh_config(settings)) as s:
        yield s


@pytest.fixture
def peers():
    """Two in-process peers: one listens on a free loopback port, the other connects to it."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    a = zenoh.open(zenoh_config(SessionSettings(listen=[ep], connect=[])))
    b = zenoh.open(zenoh_config(SessionSettings(connect=[ep])))
    assert wait_connected(b, 30.0), "the second peer never linked to the first"
    yield a, b
    b.close()
    a.close()


@pytest.fixture(scope="session")
def running_cell(tmp_path_factory):
    """The five services as separate processes, awaited by liveliness with a deadline."""
    st = make_settings()
    logs = Path(tmp_path_factory.mktemp("cell-logs"))
    cell = CellProcesses(st, log_dir=logs, data_dir=Path(tmp_path_factory.mktemp("cell-data")))
    cell.start(deadline_s=90.0)
    yield cell
    cell.stop()


@pytest.fixture(scope="module")
def cert(cell):
    """The collision certifier of the test module's ``cell`` fixture."""
    from fabric.collision.certify import Certifier
    return Certifier(cell)
