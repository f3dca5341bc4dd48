"""Collision service: certifies programs (by id, fetched from the planner) and the station's live moves.

A program is certified against its own beads, each an obstacle from the row
after it is laid (:class:`fabric.collision.certify.Certifier`). A live move
(home, recover, a restart at a layer with its straight descent onto the
part) is certified against the beads the
twin has actually laid: with ``beads="station"`` the service asks
``station/beads`` for them, a page at a time, and keeps them, so a million
beads cross the fabric once per part and each later check asks only for the
beads laid since. The alternative, the station sending its beads with every
request, would move tens of MB per ``home``.

The rest of a program (``from_row``: a restart at a layer, a recovery) is
certified on the part on the plate: its moves from that row on against the
station's beads, every one an obstacle from the start, and the beads it lays
itself (the tip's exemption as in any print); and none of its beads may go
into the part (:mod:`fabric.sim.material`: printing a layer the part already
has is such a case, which no sweep sees: the tip runs over the old beads' top).

``sweep_program`` is version 1's sampled sweep (joint configurations every few
degrees against one box per layer), kept for comparison (tools/bench/collision_bench.py).
"""
from __future__ import annotations

import argparse
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from fabric import schemas as s
from fabric.client import Client
from fabric.collision.beads import BeadSolids
from fabric.collision.certify import Certifier
from fabric.collision.report import collision_report, deposit_report
from fabric.collision.sweep import CollisionChecker, layer_boxes
from fabric.motion.program import Program
from fabric.motion.timing import time_program
from fabric.programs import program_from_artifact
from fabric.robot.cell import Cell
from fabric.server.service import Service
from fabric.sim.material import PlateMaterial, program_beads
from fabric.wire.config import add_cell_argument, service_data_dir
from fabric.wire.errors import BadRequest

__all__ = ["CollisionService", "StationBeads", "build", "add_arguments", "sweep_program"]


def sweep_program(checker: CollisionChecker, program: Program, step_deg: float, include_part: bool,
                  t_end_s: np.ndarray | None = None) -> s.CollisionReport:
    """Version 1's sampled sweep of a whole program (kept for comparison): the first hit with its time,
    row, G-code line and bodies, and the smallest clearance seen at the samples (not a bound)."""
    t0 = time.perf_counter()
    qs, rows, frac = checker.sample(program, None, step_deg)
    boxes = layer_boxes(program, program.wobj) if include_part else None
    layers = np.maximum(program.layer[rows], 0) if include_part else None
    hit, min_d, n = checker.check_configs(qs, rows, layers, boxes)
    first = None
    if hit is not None:
        row = hit.row
        t_s = -1.0
        if t_end_s is not None:
            t_start = t_end_s[row - 1] if row > 0 else 0.0
            t_s = float(t_start + (t_end_s[row] - t_start) * frac[hit.config])
        first = s.CollisionHit(body_a=hit.body_a, body_b=hit.body_b, t_s=t_s, row=row,
                               gcode_line=int(program.gcode_line[row]), layer=int(program.layer[row]))
    return s.CollisionReport(collision_free=hit is None, checked_configs=n,
                             min_distance_mm=float(min_d) if np.isfinite(min_d) else -1.0,
                             first_hit=first, elapsed_s=time.perf_counter() - t0)


class StationBeads:
    """The beads the station's twin has laid, kept as bead solids and brought up to date page by page."""

    def __init__(self, client: Client) -> None:
        self.client = client
        self.part_id = ""
        self.solids = BeadSolids.empty()
        self.wobj = np.eye(4)
        self.arrays: dict[str, list[np.ndarray]] = {}       # the pages as they came (for PlateMaterial)

    def current(self) -> BeadSolids:
        """Every bead laid so far: the ones kept, and those laid since (all of them for another part)."""
        page = self._page(len(self.solids))
        if page.part_id != self.part_id or page.total < len(self.solids) or page.first != len(self.solids):
            self.part_id, self.solids, self.arrays = page.part_id, BeadSolids.empty(), {}
            page = self._page(0) if page.first != 0 else page
        self.wobj = np.asarray(page.wobj, dtype=float)
        while True:
            if len(page.row):
                arrays = {"start_mm": page.start_mm, "end_mm": page.end_mm, "width_mm": page.width_mm,
                          "height_mm": page.height_mm, "layer": page.layer, "row": page.row, "axis": page.axis}
                self.solids = self.solids.extend(BeadSolids.from_arrays(arrays, self.wobj, page.gcode_line))
                for k, v in {**arrays, "gcode_line": page.gcode_line}.items():
                    self.arrays.setdefault(k, []).append(np.asarray(v))
            if len(self.solids) >= page.total or not len(page.row):
                return self.solids
            page = self._page(len(self.solids))

    def material(self) -> PlateMaterial:
        """The beads kept (call :meth:`current` first) as the material on the plate."""
        cols = {k: np.concatenate(v) for k, v in self.arrays.items()}
        if not cols:
            return PlateMaterial(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0))
        return PlateMaterial(cols["start_mm"], cols["end_mm"], cols["width_mm"], cols["height_mm"], cols["layer"])

    def gcode_lines(self) -> np.ndarray:
        """The G-code line that laid each bead kept (-1: not known)."""
        return np.concatenate(self.arrays["gcode_line"]) if self.arrays else np.zeros(0, np.int64)

    def _page(self, first: int) -> s.Beads:
        return self.client.call("station", "beads", s.BeadsQuery(first=first, limit=s.pipeline.MAX_BEADS_PAGE))


class CollisionService(Service):
    name = "collision"

    def __init__(self, session: zenoh.Session, cell_id: str, cell: Cell, data_dir: Path | None = None) -> None:
        super().__init__(session, cell_id, data_dir)
        self.cell = cell
        self.client = Client(session, cell_id)
        self._certifiers: dict[tuple[str, float], Certifier] = {}
        self._certifier("move", 0.01)                      # built now: the first check does not wait for it
        self._cache: dict[str, tuple[Program, BeadSolids]] = {}
        self._times: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.station_beads = StationBeads(self.client)
        # Programs and live moves are checked apart: the station's home or jog (milliseconds) does not wait
        # behind a program of a million moves (tens of seconds). Each side has its own certifiers.
        self._locks = {"program": threading.Lock(), "move": threading.Lock()}
        self.handle("check", self.on_check, workers=3)     # a program being checked leaves two for live moves

    def _certifier(self, side: str, tolerance_mm: float) -> Certifier:
        key = (side, round(float(tolerance_mm), 6))
        if key not in self._certifiers:
            self._certifiers[key] = Certifier(self.cell, key[1])
        return self._certifiers[key]

    def _program(self, program_id: str) -> tuple[Program, BeadSolids]:
        if program_id not in self._cache:
            program = program_from_artifact(self.client.artifact("planner", program_id))
            self._cache = {program_id: (program, BeadSolids.from_program(program))}
            self._times = {}
        return self._cache[program_id]

    def _row_times(self, program_id: str, program: Program) -> tuple[np.ndarray, np.ndarray]:
        if program_id not in self._times:
            tl = time_program(program, self.cell.robot)
            self._times = {program_id: (tl.t_start_s, tl.t_end_s)}
        return self._times[program_id]

    def on_check(self, req: s.CollisionRequest) -> s.CollisionReport:
        side = "program" if req.program_id else "move"
        with self._locks[side]:
            cert = self._certifier(side, req.tolerance_mm)
            if req.program_id:
                return self._check_program(req, cert)
            return self._check_move(req, cert)

    def _check_program(self, req: s.CollisionRequest, cert: Certifier) -> s.CollisionReport:
        if req.from_row >= 0:
            return self._check_rest(req, cert)
        program, solids = self._program(req.program_id)
        q0 = self._joints("q_start_deg", req.q_start_deg) if req.q_start_deg is not None else None
        beads = solids if req.include_part else BeadSolids.empty()
        res = cert.sweep_program(program, q0, beads)
        return collision_report(res, cert, beads, program.wobj, program,
                                lambda: self._row_times(req.program_id, program))

    def _check_rest(self, req: s.CollisionRequest, cert: Certifier) -> s.CollisionReport:
        """The program from ``from_row`` on the part on the plate (module docstring): its beads first (none
        into the part), then its moves."""
        t0 = time.perf_counter()
        program, _ = self._program(req.program_id)
        if req.from_row >= len(program):
            raise BadRequest(f"from_row {req.from_row} is past the program's last row ({len(program) - 1})",
                             field="from_row")
        plate, wobj = BeadSolids.empty(), program.wobj
        if req.beads == "station":
            plate, wobj = self.station_beads.current(), self.station_beads.wobj
            new = program_beads(program, req.from_row + 1)    # from_row may be one cut short: it goes on
            into = self.station_beads.material().first_overlap(new)
            if into is not None:
                return deposit_report(program, new, into, self.station_beads, cert, time.perf_counter() - t0)
        q0 = self._joints("q_start_deg", req.q_start_deg) if req.q_start_deg is not None else None
        rest = program.slice(req.from_row)
        beads = plate.laid_before().extend(BeadSolids.from_program(rest))
        report = collision_report(cert.sweep_program(rest, q0, beads), cert, beads, wobj, rest)
        if report.first_hit is not None:
            report.first_hit.row += req.from_row
        return report

    def _check_move(self, req: s.CollisionRequest, cert: Certifier) -> s.CollisionReport:
        if req.q_from_deg is None or req.q_to_deg is None:
            raise BadRequest("give a program_id, or both q_from_deg and q_to_deg", field="program_id")
        q0, q1 = self._joints("q_from_deg", req.q_from_deg), self._joints("q_to_deg", req.q_to_deg)
        beads, wobj = BeadSolids.empty(), self.cell.wobj_T()
        if req.beads == "station":
            beads, wobj = self.station_beads.current(), self.station_beads.wobj
        tip_layer = req.tip_layer
        if tip_layer == -2:                                # where the nozzle rests: the last bead's layer
            tip_layer = int(beads.layer[-1]) if len(beads) else -1
        q_down = self._joints("q_down_deg", req.q_down_deg) if req.q_down_deg is not None else None
        res = cert.sweep_move(q0, q1, beads, tip_layer, req.vel_r, req.kind, q_down, req.down_layer)
        return collision_report(res, cert, beads, wobj)

    def _joints(self, name: str, deg: list[float]) -> np.ndarray:
        nq = self.cell.robot.nq
        if len(deg) != nq:
            raise BadRequest(f"{name} has {len(deg)} joints, the robot has {nq}", field=name)
        return np.radians(np.asarray(deg, dtype=float))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_cell_argument(parser)


def build(session: zenoh.Session, cell_id: str, options: argparse.Namespace) -> CollisionService:
    cell = Cell.load_or_builtin(options.cell_config)
    return CollisionService(session, cell_id, cell, service_data_dir(options.data_dir, cell_id, "collision"))
