"""A small hand-built print program (a square tower at the plate centre) for tests and benchmarks.

Rows: optional heat-up (SET_TEMP / WAIT_TEMP for bed and nozzle), a MoveJ from
home to above the first corner at the cell's approach height, a linear move
down to the first layer, then per layer the four sides of the square as
extruding linear moves (flow = bead cross-section, Slic3r's rounded
rectangle) and a short non-extruding move up to the next layer; finally a
linear move up to the approach height and a MoveJ home. The nozzle points
down the plate normal (TCP z = -plate z); joints come from ``cell.robot.ik``
solved along the whole path from the home joints.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from fabric.motion.program import APPROACH, BED, MOVEJ, MOVEL, NOZZLE, PRINT, RETURN_HOME, SET_TEMP, WAIT_TEMP, Program
from fabric.robot.frames import inv_T, make_T, quat_from_R, rot_x
from fabric.robot.kinematics import IK_OK, IK_SINGULAR, ik_reason
from fabric.sim.deposition import bead_area_mm2
from fabric.wire.errors import UnreachableError

__all__ = ["square_program"]


def square_program(cell: Any, size_mm: float = 20.0, layers: int = 3, layer_height_mm: float = 0.5,
                   speed_mm_s: float = 30.0, *, bead_width_mm: float = 0.8, zone_mm: float = 0.1,
                   centre_mm: tuple[float, float] | None = None, nozzle_c: float | None = None,
                   bed_c: float | None = None, vel_r: float = 0.5) -> Program:
    """A ``layers``-high square of side ``size_mm`` centred at ``centre_mm`` (work-object frame; default
    the plate's centre)."""
    plate = np.asarray(cell.plate_size_mm, dtype=float)
    cx, cy = centre_mm if centre_mm is not None else (plate[0] / 2.0, plate[1] / 2.0)
    h = size_mm / 2.0
    corners = np.array([[cx - h, cy - h], [cx + h, cy - h], [cx + h, cy + h], [cx - h, cy + h], [cx - h, cy - h]])
    flow = float(bead_area_mm2(np.array(bead_width_mm), np.array(layer_height_mm)))
    approach_z = float(getattr(cell, "approach_height_mm", 50.0))
    rows: list[dict[str, Any]] = []
    if bed_c is not None:
        rows.append({"op": SET_TEMP, "aux": BED, "value": bed_c, "section": APPROACH})
    if nozzle_c is not None:
        rows.append({"op": SET_TEMP, "aux": NOZZLE, "value": nozzle_c, "section": APPROACH})
    if bed_c is not None:
        rows.append({"op": WAIT_TEMP, "aux": BED, "value": bed_c, "section": APPROACH})
    if nozzle_c is not None:
        rows.append({"op": WAIT_TEMP, "aux": NOZZLE, "value": nozzle_c, "section": APPROACH})
    n_heat = len(rows)
    first = np.array([*corners[0], approach_z])
    rows.append({"op": MOVEJ, "xyz": first, "vel_r": vel_r, "section": APPROACH})
    approach_speed = float(getattr(cell, "approach_speed_mm_s", 50.0))
    rows.append({"op": MOVEL, "xyz": np.array([*corners[0], layer_height_mm]), "speed": approach_speed,
                 "section": APPROACH})
    for layer in range(layers):
        z = (layer + 1) * layer_height_mm
        for c in corners[1:]:
            rows.append({"op": MOVEL, "xyz": np.array([*c, z]), "speed": speed_mm_s, "flow": flow,
                         "zone": zone_mm, "layer": layer, "section": PRINT})
        if layer + 1 < layers:
            rows.append({"op": MOVEL, "xyz": np.array([*corners[0], z + layer_height_mm]), "speed": speed_mm_s,
                         "layer": layer + 1, "section": PRINT})
    rows.append({"op": MOVEL, "xyz": np.array([*corners[0], approach_z]), "speed": approach_speed,
                 "section": RETURN_HOME})
    rows.append({"op": MOVEJ, "home": True, "vel_r": vel_r, "section": RETURN_HOME})

    p = Program.empty(len(rows), nq=cell.robot.nq, bead_width_mm=bead_width_mm, layer_height_mm=layer_height_mm,
                      source="square")
    p.wobj = np.asarray(cell.wobj_T(), dtype=float)
    R_tool = rot_x(np.pi)                       # nozzle (TCP +z) pointing down the plate normal
    quat = quat_from_R(R_tool)
    home = np.asarray(cell.home_q_rad, dtype=float)
    motion = [i for i, r in enumerate(rows) if "xyz" in r]
    T = make_T(np.broadcast_to(R_tool, (len(motion), 3, 3)), np.array([rows[i]["xyz"] for i in motion]))
    q, status = cell.robot.ik(p.wobj @ T, home)
    bad = np.flatnonzero(~np.isin(status, (IK_OK, IK_SINGULAR)))
    if len(bad):
        reason = ik_reason(status[bad[0]])
        raise UnreachableError(f"square program row {motion[bad[0]]} is unreachable ({reason})",
                               row=motion[bad[0]], gcode_line=-1, reason=reason)
    Th = inv_T(p.wobj) @ np.asarray(cell.robot.fk(home[None]))[0]
    last_q, last_xyz, last_quat = home, Th[:3, 3], quat_from_R(Th[:3, :3])
    k = 0
    for i, r in enumerate(rows):
        if "xyz" in r:
            last_q, last_xyz, last_quat = q[k], r["xyz"], quat
            k += 1
        elif r.get("home"):
            last_q, last_xyz, last_quat = home, Th[:3, 3], quat_from_R(Th[:3, :3])
        p.op[i], p.section[i] = r["op"], r["section"]
        p.q_rad[i], p.xyz_mm[i], p.quat_wxyz[i] = last_q, last_xyz, last_quat
        p.speed_mm_s[i] = r.get("speed", 0.0)
        p.vel_r[i] = r.get("vel_r", 0.0)
        p.zone_mm[i] = r.get("zone", 0.0)
        p.flow_mm3_mm[i] = r.get("flow", 0.0)
        p.value[i] = r.get("value", 0.0)
        p.aux[i] = r.get("aux", 0)
        p.layer[i] = r.get("layer", -1)
        p.gcode_line[i] = 10 + i - n_heat if i >= n_heat else i + 1
    return p
