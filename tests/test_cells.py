"""Ten cells on one hub: each station its own process, listed by ``fabric-cli cells``, and no cross-talk."""
from __future__ import annotations

import json
import subprocess
import sys
import uuid
from dataclasses import replace

import pytest
import zenoh

from fabric import schemas as s
from fabric.cli.up import CellProcesses, hub_settings
from fabric.client import Client
from fabric.wire import codec
from fabric.wire.config import zenoh_config
from fabric.wire.keys import Keys, parse_alive

from support.loopback import make_settings

pytestmark = pytest.mark.timeout(180)
CELLS = 10


@pytest.fixture(scope="module")
def ten_cells(tmp_path_factory):
    """One hub; ten cells, each a station process of its own (started together, awaited by liveliness)."""
    base = make_settings()
    tag = uuid.uuid4().hex[:6]
    names = [f"c{tag}-{k}" for k in range(CELLS)]
    data, logs = tmp_path_factory.mktemp("cells-data"), tmp_path_factory.mktemp("cells-logs")
    cells = [CellProcesses(replace(base, cell=name), services=("station",), host_hub=False, log_dir=logs,
                           data_dir=data, extra_args={"station": ["--pose-hz", "10", "--log-level", "WARNING"]})
             for name in names]
    with zenoh.open(zenoh_config(hub_settings(base))):
        try:
            for cell in cells:
                cell.launch()
            for cell in cells:
                cell.wait_up(deadline_s=120.0)
            yield base, names
        finally:
            for cell in cells:
                cell.stop()


def test_cells_lists_every_cell(ten_cells) -> None:
    base, names = ten_cells
    with Client.connect(replace(base, mode="client")) as client:
        present = client.cells()
    assert {n: present.get(n) for n in names} == {n: ["station"] for n in names}
    out = subprocess.run([sys.executable, "-m", "fabric.cli.main", "cells", "--json", "--connect", base.connect[0]],
                         capture_output=True, text=True, timeout=60)
    rows = {row["cell"]: row for row in json.loads(out.stdout)}
    assert set(names) <= set(rows) and not any(rows[n]["complete"] for n in names)


def test_a_command_to_one_cell_changes_only_that_cell(ten_cells) -> None:
    base, names = ten_cells
    with Client.connect(replace(base, mode="client")) as client:
        every = Keys.every_cell()
        states = client.session.declare_subscriber(every.topic("station", "state"), zenoh.handlers.FifoChannel(4096))
        clients = {name: Client(client.session, name) for name in names}
        for k, name in enumerate(names):
            assert clients[name].set_rtf(2.0 + k).rtf == 2.0 + k
        assert {name: c.state().rtf for name, c in clients.items()} == {n: 2.0 + k for k, n in enumerate(names)}
        # every state published meanwhile came from its own cell with that cell's values (1.0: before the change)
        cell_of = {Keys(n).topic("station", "state"): n for n in names}
        while (sample := states.try_recv()) is not None:
            cell = cell_of.get(str(sample.key_expr))
            if cell is not None:
                rtf = codec.decode(sample.payload.to_bytes(), s.StationState).rtf
                assert rtf in (1.0, 2.0 + names.index(cell)), f"{cell} published the rtf of another cell: {rtf}"
        alive = {parse_alive(str(r.ok.key_expr)) for r in client.session.liveliness().get(every.alive_all())
                 if r.ok is not None}
        assert {(n, "station") for n in names} <= alive
