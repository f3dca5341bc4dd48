"""``fabric-cli cell show | export-urdf``: the cell a file names, else the cell the station on the fabric runs,
else the built-in default, and the CLI says which (an operator who started ``up --cell-config panda`` was shown
the IRB 140)."""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from fabric import schemas as s
from fabric.cli import cell_cmds
from fabric.client import Client
from fabric.robot.cell import Cell
from fabric.services.station import StationService
from fabric.wire.errors import NotFound

from support.loopback import free_port

pytestmark = pytest.mark.timeout(180)

CELLS = Path(__file__).resolve().parents[1] / "fabric" / "cells"


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fabric.cli.main", *args], capture_output=True, text=True,
                          timeout=120)


def nobody() -> list[str]:
    """Session flags of a fabric with no hub: a loopback port nothing listens on."""
    return ["--connect", f"tcp/127.0.0.1:{free_port()}"]


def test_without_a_station_the_default_cell_and_the_cli_says_so(tmp_path):
    r = cli("cell", "show", *nobody())
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("name: irb140") and "no station of cell" in r.stderr and "default" in r.stderr
    r = cli("cell", "show", "--json", *nobody())
    assert r.returncode == 0 and json.loads(r.stdout)["name"] == "irb140" and r.stderr == ""
    out = tmp_path / "cell.urdf"
    r = cli("cell", "export-urdf", str(out), *nobody())
    assert r.returncode == 0 and 'name="tcp"' in out.read_text() and "irb140" in r.stdout


def test_a_cell_file_or_name_is_read_here_without_the_fabric(tmp_path):
    ur5 = CELLS / "ur5.toml"
    r = cli("cell", "show", "--cell-config", str(ur5), *nobody())
    assert r.returncode == 0 and r.stdout.startswith("name: ur5") and r.stderr == ""
    r = cli("cell", "show", "--cell-config", "kr6r700", "--json", *nobody())
    assert r.returncode == 0 and json.loads(r.stdout)["native_export"] == "krl"
    bad = tmp_path / "bad.toml"
    bad.write_text(ur5.read_text() + "\n[bogus]\nx = 1\n")
    r = cli("cell", "show", "--cell-config", str(bad), *nobody())
    assert r.returncode == 1 and "error [config]" in r.stderr and "bogus" in r.stderr


def test_the_cell_the_station_runs_is_shown(session, settings, tmp_path):
    station = StationService(session, settings.cell, Cell.builtin("ur5"), data_dir=tmp_path / "station")
    station.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("station",), deadline_s=30)
        args = replace(settings, mode="client").to_args()
        r = cli("cell", "show", *args)
        assert r.returncode == 0, r.stderr
        assert r.stdout.startswith("name: ur5") and f"the cell the station of '{settings.cell}' runs: ur5" in r.stderr
        out = tmp_path / "running.urdf"
        r = cli("cell", "export-urdf", str(out), "--json", *args)
        assert r.returncode == 0 and json.loads(r.stdout)["robot"] == "ur5" and 'name="tcp"' in out.read_text()
        # --cell-config still wins over the running cell
        r = cli("cell", "show", "--cell-config", "panda", *args)
        assert r.returncode == 0 and r.stdout.startswith("name: panda")
    finally:
        station.close()


def test_a_station_running_a_cell_file_is_named_not_mistaken_for_the_built_in(monkeypatch):
    """A cell file named like a built-in cell but configured otherwise (another fingerprint) is not shown as the
    built-in one: the error names what the station reports and asks for the file."""
    ur5 = Cell.builtin("ur5")
    info = s.CellInfo(name="ur5", robot="ur5", ik_family="ur", joint_names=["a"] * 6,
                      fingerprint="0" * len(ur5.fingerprint()))
    monkeypatch.setattr(cell_cmds, "running_cell", lambda a: cell_cmds.RunningCell(info, "c1"))
    a = argparse.Namespace(cell_config=None, json=False)
    with pytest.raises(NotFound, match=r"runs cell 'ur5' \(ur5, 6 joints, ur IK\) from a cell file.*--cell-config"):
        cell_cmds._cell_of(a)
    info.fingerprint = ur5.fingerprint()                     # the same configuration: it is the built-in one
    assert cell_cmds._cell_of(a).name == "ur5"
