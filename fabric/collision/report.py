"""A certified sweep's result as the wire report: the first hit in words (G-code line, move, bodies, where,
when, the bead touched) and where the clearance is smallest."""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from fabric import schemas as s
from fabric.collision.beads import BeadSolids
from fabric.collision.certify import Certifier, SweepResult
from fabric.collision.path import MOVE_KINDS
from fabric.motion.program import Program
from fabric.robot.frames import inv_T
from fabric.sim.material import NewBeads, Overlap

__all__ = ["collision_report", "deposit_report", "hit_message"]


def collision_report(res: SweepResult, cert: Certifier, beads: BeadSolids, wobj: np.ndarray,
                     program: Program | None = None,
                     row_times: Callable[[], tuple[np.ndarray, np.ndarray]] | None = None) -> s.CollisionReport:
    """The report of ``res``: ``program`` names rows (G-code lines, layers; None for a live move), ``wobj``
    is the plate frame of the tip positions, ``row_times`` gives (t_start_s, t_end_s) per row when a hit
    needs its time (computed only then)."""
    segs = res.segs
    assert segs is not None, "a sweep result carries its path"
    hit = None
    h = res.first_hit
    if h is not None:
        tcp = inv_T(np.asarray(wobj, dtype=float)) @ cert.cell.robot.fk(h.q_rad[None])[0]
        line = layer = -1
        t_s = -1.0
        if program is not None:
            line, layer = int(program.gcode_line[h.row]), int(program.layer[h.row])
            if row_times is not None:
                t0, t1 = row_times()
                t_s = float(t0[h.row] + (t1[h.row] - t0[h.row]) * h.s)
        bead_layer = int(beads.layer[h.bead]) if h.bead >= 0 else -1
        bead_line = int(beads.gcode_line[h.bead]) if h.bead >= 0 else -1
        hit = s.CollisionHit(body_a=h.body, body_b=h.other, t_s=t_s, row=h.row if program is not None else -1,
                             gcode_line=line, layer=layer, move_r=float(np.clip(h.s, 0.0, 1.0)),
                             kind=MOVE_KINDS[int(segs.kind[h.segment])],
                             xyz_mm=[float(v) for v in tcp[:3, 3]], distance_mm=float(h.distance_mm), bead=h.bead,
                             bead_layer=bead_layer, bead_gcode_line=bead_line)
        hit.message = hit_message(hit)
    clearance = res.clearance_mm if np.isfinite(res.clearance_mm) else -1.0
    c_line = c_layer = -1
    if program is not None and res.clearance_segment >= 0:
        row = int(segs.row[res.clearance_segment])
        c_line, c_layer = int(program.gcode_line[row]), int(program.layer[row])
    return s.CollisionReport(collision_free=res.collision_free, checked_configs=res.configs,
                             min_distance_mm=float(clearance) if hit is None else 0.0, first_hit=hit,
                             elapsed_s=res.elapsed_s, clearance_body=res.clearance_body,
                             clearance_gcode_line=c_line, clearance_layer=c_layer, segments=res.segments,
                             swept_pieces=res.pieces, beads=res.beads, exemption=cert.exemption,
                             tolerance_mm=cert.tol)


def deposit_report(program: Program, new: NewBeads, into: Overlap, plate: Any, cert: Certifier,
                   elapsed_s: float) -> s.CollisionReport:
    """The report of a program whose bead ``new[into.new]`` would go into the part on the plate (``plate``:
    its ``material()`` and ``gcode_lines()``; the bead ``into.existing``): kind ``deposit``, body_a ``bead``."""
    row = int(new.row[into.new])
    material = plate.material()
    lines = plate.gcode_lines()
    hit = s.CollisionHit(body_a="bead", body_b="part", row=row, gcode_line=int(program.gcode_line[row]),
                         layer=int(program.layer[row]), kind="deposit",
                         xyz_mm=[float(v) for v in new.start_mm[into.new]], distance_mm=-float(into.length_mm),
                         bead=into.existing, bead_layer=int(material.layer[into.existing]),
                         bead_gcode_line=int(lines[into.existing]) if len(lines) > into.existing else -1)
    hit.message = hit_message(hit)
    return s.CollisionReport(collision_free=False, checked_configs=0, min_distance_mm=0.0, first_hit=hit,
                             elapsed_s=elapsed_s, beads=len(material), exemption=cert.exemption,
                             tolerance_mm=cert.tol)


def hit_message(hit: s.CollisionHit) -> str:
    """``G-code line 1234 (travel, layer 34): tool_nozzle hits the part (a bead of layer 33 laid by G-code
    line 1200) at (125.0, 80.0, 8.0) mm, t = 312.4 s``."""
    where = []
    if hit.gcode_line >= 0:
        where.append(f"G-code line {hit.gcode_line}")
    what = hit.kind or "move"
    if hit.layer >= 0:
        what += f", layer {hit.layer + 1}"
    head = f"{' '.join(where)} ({what})" if where else f"the {what} move"
    if hit.kind == "deposit":                      # not a move: a bead laid into the part on the plate
        into = f"a bead of layer {hit.bead_layer + 1}" + (
            f" laid by G-code line {hit.bead_gcode_line}" if hit.bead_gcode_line >= 0 else "")
        return (f"{head}: its bead would go into the part on the plate ({into}), {-hit.distance_mm:.1f} mm along "
                f"it")
    other = {"part": "the part", "plate": "the plate", "table": "the table"}.get(hit.body_b, hit.body_b)
    if hit.body_b == "part" and hit.bead_layer >= 0:
        other += f" (a bead of layer {hit.bead_layer + 1}" + (
            f" laid by G-code line {hit.bead_gcode_line})" if hit.bead_gcode_line >= 0 else ")")
    text = f"{head}: {hit.body_a} hits {other}"
    if hit.xyz_mm is not None:
        text += " with the nozzle at (" + ", ".join(f"{v:.1f}" for v in hit.xyz_mm) + ") mm"
    if hit.t_s >= 0:
        text += f", t = {hit.t_s:.1f} s"
    elif hit.row < 0:
        text += f", {100 * hit.move_r:.0f} % of the way"
    return text
