"""Collision service: sweeps programs (by id, fetched from the planner) and single joint moves."""
from __future__ import annotations

import argparse
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from fabric import schemas as s
from fabric.client import Client
from fabric.collision.sweep import CollisionChecker, layer_boxes
from fabric.motion.program import Program
from fabric.motion.timing import time_program
from fabric.programs import program_from_artifact
from fabric.robot.cell import Cell
from fabric.server.service import Service
from fabric.wire.config import add_cell_argument, service_data_dir
from fabric.wire.errors import BadRequest

__all__ = ["CollisionService", "build", "add_arguments", "sweep_program"]


def sweep_program(checker: CollisionChecker, program: Program, step_deg: float, include_part: bool,
                  t_end_s: np.ndarray | None = None) -> s.CollisionReport:
    """Sweep a whole program; report the first hit with its time, row, G-code line and bodies."""
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


class CollisionService(Service):
    name = "collision"

    def __init__(self, session: zenoh.Session, cell_id: str, cell: Cell, data_dir: Path | None = None) -> None:
        super().__init__(session, cell_id, data_dir)
        self.checker = CollisionChecker(cell)
        self.cell = cell
        self.client = Client(session, cell_id)
        self._cache: dict[str, Program] = {}
        self._check_lock = threading.Lock()
        self.handle("check", self.on_check)

    def _program(self, program_id: str) -> Program:
        if program_id not in self._cache:
            self._cache = {program_id: program_from_artifact(self.client.artifact("planner", program_id))}
        return self._cache[program_id]

    def on_check(self, req: s.CollisionRequest) -> s.CollisionReport:
        nq = self.cell.robot.nq
        with self._check_lock:
            if req.program_id:
                program = self._program(req.program_id)
                t_end = _timeline_ends(program, self.cell)
                return sweep_program(self.checker, program, req.step_deg, req.include_part, t_end)
            if req.q_from_deg is None or req.q_to_deg is None:
                raise BadRequest("give a program_id, or both q_from_deg and q_to_deg", field="program_id")
            for name, v in (("q_from_deg", req.q_from_deg), ("q_to_deg", req.q_to_deg)):
                if len(v) != nq:
                    raise BadRequest(f"{name} has {len(v)} joints, the robot has {nq}", field=name)
            t0 = time.perf_counter()
            q0, q1 = np.radians(req.q_from_deg), np.radians(req.q_to_deg)
            n = int(max(1, np.ceil(np.abs(q1 - q0).max() / np.radians(req.step_deg))))
            qs = q0 + (q1 - q0) * np.linspace(0.0, 1.0, n + 1)[:, None]
            hit, min_d, checked = self.checker.check_configs(qs)
            first = None
            if hit is not None:
                first = s.CollisionHit(body_a=hit.body_a, body_b=hit.body_b, move_r=float(hit.config / n))
            return s.CollisionReport(collision_free=hit is None, checked_configs=checked,
                                     min_distance_mm=float(min_d) if np.isfinite(min_d) else -1.0,
                                     first_hit=first, elapsed_s=time.perf_counter() - t0)


def _timeline_ends(program: Program, cell: Cell) -> np.ndarray:
    return time_program(program, cell.robot).t_end_s


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_cell_argument(parser)


def build(session: zenoh.Session, cell_id: str, options: argparse.Namespace) -> CollisionService:
    cell = Cell.load_or_builtin(options.cell_config)
    return CollisionService(session, cell_id, cell, service_data_dir(options.data_dir, cell_id, "collision"))
