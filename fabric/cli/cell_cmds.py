"""``fabric-cli cell show | list | export-urdf``: the cell model, read here (no service needed for a file).

Without ``--cell-config``, ``show`` and ``export-urdf`` are about the cell that is running: the station on the
fabric is asked which cell it runs (its name and the fingerprint of its configuration), and a built-in cell of
that name whose configuration has the same fingerprint is the one shown. A station running a cell file (its
file may be on another host) gets what it reports, with a word on how to see the whole file; with no station
on the fabric, the built-in default cell is shown and the CLI says so.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING

from fabric import schemas as s
from fabric.cli.output import emit
from fabric.client import Client
from fabric.wire.config import add_cell_argument, settings_from_args
from fabric.wire.errors import FabricError, NotFound

if TYPE_CHECKING:
    from fabric.robot.cell import Cell

__all__ = ["register", "RunningCell", "running_cell"]

ASK_WINDOW_S = 1.0      # how long to wait for the hub and the station before showing the default cell


@dataclass
class RunningCell:
    """What the station of cell ``cell_id`` says it runs (None: no station answered; ``why`` not, when known)."""

    info: s.CellInfo | None
    cell_id: str
    why: str = ""


def running_cell(a: argparse.Namespace) -> RunningCell:
    """Ask the station of ``--cell`` which cell it runs; no hub or no station is an answer too (None)."""
    settings = settings_from_args(a, default_mode="client")
    try:
        with Client.connect(settings, ASK_WINDOW_S) as client:
            return RunningCell(client.station_cell(timeout=ASK_WINDOW_S), settings.cell)
    except FabricError as err:                  # no hub, refused credentials, ...: said with the default
        return RunningCell(None, settings.cell, err.message)


def _cell_of(a: argparse.Namespace) -> Cell:
    """The cell ``--cell-config`` names, else the one the station runs, else the built-in default."""
    from fabric.robot.cell import DEFAULT_CELL, Cell, builtin_cell_names  # the robot model: not at import
    if a.cell_config is not None:
        return Cell.load_or_builtin(a.cell_config)
    running = running_cell(a)
    info = running.info
    if info is None:
        why = f" ({running.why})" if running.why else ""
        _note(a, f"no station of cell '{running.cell_id}' answered{why}: the built-in default cell {DEFAULT_CELL} "
                 "(--cell-config NAME|FILE for another)")
        return Cell.builtin(DEFAULT_CELL)
    if info.name in builtin_cell_names():
        cell = Cell.builtin(info.name)
        if cell.fingerprint() == info.fingerprint:
            _note(a, f"the cell the station of '{running.cell_id}' runs: {info.name} (built-in)")
            return cell
    raise NotFound(f"the station of '{running.cell_id}' runs cell '{info.name}' ({info.robot}, "
                   f"{len(info.joint_names)} joints, {info.ik_family} IK) from a cell file, not a built-in cell: "
                   "give that file with --cell-config FILE", cell=info.name, fingerprint=info.fingerprint)


def _note(a: argparse.Namespace, text: str) -> None:
    """Which cell this is, on stderr (stdout stays the cell itself, for scripts)."""
    if not a.json:
        print(text, file=sys.stderr, flush=True)


def cmd_show(a: argparse.Namespace) -> int:
    emit(_cell_of(a).to_dict(), a.json)
    return 0


def cmd_list(a: argparse.Namespace) -> int:
    from fabric.robot.cell import DEFAULT_CELL, Cell, builtin_cell_names
    names = builtin_cell_names()
    rows = []
    for name in names:
        cell = Cell.builtin(name)
        r = cell.robot
        rows.append({"cell": name, "robot": r.name, "joints": r.nq, "ik_family": r.ik_family,
                     "export": cell.native_export, "default": name == DEFAULT_CELL})
    w = max(len(name) for name in names)
    emit(rows, a.json, lambda rs: "\n".join(
        (f"{x['cell']:<{w}}  {x['robot']:<10} {x['joints']} joints  IK {x['ik_family']:<8} export {x['export']:<8}"
         + ("  (default)" if x["default"] else "")).rstrip() for x in rs))
    return 0


def cmd_export_urdf(a: argparse.Namespace) -> int:
    cell = _cell_of(a)
    cell.robot.export_urdf(a.output)
    emit({"path": a.output, "robot": cell.robot.name, "tcp_frame": "tcp"}, a.json,
         lambda d: f"wrote {d['path']} ({d['robot']} + tool, TCP frame 'tcp')")
    return 0


def register(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    what = "default: the cell the station on the fabric runs, else the built-in IRB 140 cell"
    cell = sub.add_parser("cell", help="the cell configuration")
    csub = cell.add_subparsers(dest="cell_cmd", required=True)
    p = csub.add_parser("show", parents=[common], help="print the cell (robot, frames, plate, home)")
    add_cell_argument(p, default=what)
    p.set_defaults(local=cmd_show)
    p = csub.add_parser("list", parents=[common],
                        help="the built-in cells: robot, joints, detected IK family, native export")
    p.set_defaults(local=cmd_list)
    p = csub.add_parser("export-urdf", parents=[common], help="write robot + tool as one URDF (TCP frame 'tcp')")
    p.add_argument("output")
    add_cell_argument(p, default=what)
    p.set_defaults(local=cmd_export_urdf)
