"""An unreachable target's reason names the joint, its angle and limit, and the G-code line (issue 38): in the
plan summary (the protocol), the print job's record and error, the console's job view and the command line.

A curved-layer part planned on irb140-multiaxis once came back "not runnable: 338 targets at joint limit" with
the reason's detail empty. The program here is a ring printed with the nozzle leaning 52 deg away from the
robot, which bends A5 past its 115 deg."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace

import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.robot.cell import Cell
from fabric.robot.frames import T_to_xyzrpy
from fabric.server.service import Service
from fabric.services.planner import PlannerService
from fabric.services.supervisor import SupervisorService
from fabric.tui.format import job_report
from fabric.wire.errors import UnreachableError

pytestmark = pytest.mark.timeout(120)

CELL_NAME = "irb140-multiaxis"
WAIT_S = 60.0            # a deadline: planning the ring takes about a second
HEAD = ("; multiaxis: nozzle axis in I J K\n; filament_diameter = 2.85\n;TYPE:Custom\nM104 S210\nM109 S210\n"
        "G21\nG90\nM83\n;WIDTH:0.450\n")


def leaning_ring(lean_deg: float = 52.0, n: int = 48, radius_mm: float = 10.0) -> tuple[bytes, int]:
    """A vertical ring, then one above it with the nozzle leaning ``lean_deg`` towards +x (away from the robot);
    and the G-code line (1-based) of the travel that turns the nozzle to lean so."""
    lines = HEAD.rstrip("\n").split("\n")
    first_leaning = -1
    for layer, lean in enumerate((0.0, lean_deg)):
        z = 0.3 * (layer + 1)
        t = math.radians(lean)
        lines += [";LAYER_CHANGE", f";Z:{z:.3f}", ";HEIGHT:0.300"]
        for k in range(n + 1):
            a = 2 * math.pi * k / n
            move = (f"X{125 + radius_mm * math.cos(a):.4f} Y{125 + radius_mm * math.sin(a):.4f} Z{z:.3f} "
                    f"I{math.sin(t):.6f} J0 K{math.cos(t):.6f}")
            lines.append(f"G0 {move} F6000" if k == 0 else f"G1 {move} E0.024 F1200")
            if layer == 1 and k == 0:
                first_leaning = len(lines)
    return ("\n".join(lines) + "\n").encode(), first_leaning


def _says_which_joint(text: str, line: int) -> None:
    assert f"G-code line {line}" in text, text
    assert "joint limit: A5 at 1" in text and "deg, past its limit 115 deg" in text, text


class StandInStation(Service):
    """The station as the supervisor asks it before planning: its state, with the cell's work object."""

    name = "station"
    partial = True

    def __init__(self, session, cell_id: str, cell: Cell) -> None:
        super().__init__(session, cell_id)
        xyz, rpy = T_to_xyzrpy(cell.wobj_T())
        state = s.StationState(state="idle", wobj_xyz_mm=[float(v) for v in xyz],
                               wobj_rpy_deg=[float(v) for v in rpy])
        self.handle("state", lambda _: state)
        self.handle("events", lambda req: s.EventList(events=[], next_seq=req.since_seq))


def test_a_print_job_fails_naming_the_joint_its_angle_and_limit_and_the_line(memory_fabric, tmp_path):
    """The planner (the real one, on the multi-axis cell) finds A5 past its limit; the supervisor fails the job
    with that reason; the record keeps the plan and the error's figures; the console's job view shows them."""
    gcode, line = leaning_ring()
    cell_id = "cell1"
    cell = Cell.builtin(CELL_NAME)
    services = [SupervisorService(memory_fabric.session(), cell_id),
                PlannerService(memory_fabric.session(), cell_id, cell, data_dir=tmp_path / "planner"),
                StandInStation(memory_fabric.session(), cell_id, cell)]
    for svc in services:
        svc.start()
    try:
        client = Client(memory_fabric.session(), cell_id)
        client.wait_alive(("supervisor", "planner", "station"), deadline_s=WAIT_S)
        job_id = client.submit(s.JobSubmit(model=gcode, filename="ring.gcode")).job_id
        with pytest.raises(UnreachableError) as e:
            client.wait_print_job(job_id, lambda rec: False, timeout=WAIT_S)
        rec = client.job(job_id)
    finally:
        for svc in reversed(services):
            svc.close()
    _says_which_joint(str(e.value), line)
    details = e.value.details
    assert (details["gcode_line"], details["reason"], details["joint"]) == (line, "joint limit", 4)    # 0-based
    assert details["limit_deg"] == pytest.approx(115.0) and details["value_deg"] > 115.0
    assert rec.state == "failed" and rec.error is not None and rec.error.details["joint"] == 4
    _says_which_joint(rec.reason, line)
    fu = rec.plan.first_unreachable
    assert (fu.gcode_line, fu.joint, fu.limit_deg) == (line, 5, pytest.approx(115.0))
    assert set(rec.plan.unreachable_by_joint) == {"A5"}
    assert rec.plan.unreachable_by_joint["A5"] == rec.plan.unreachable_by_reason["joint limit"]
    assert f"targets at joint limit: A5 {rec.plan.unreachable_by_joint['A5']})" in rec.reason
    shown = job_report(rec)
    reach = [ln for ln in shown.splitlines() if ln.startswith("reach")]
    assert len(reach) == 1 and reach[0].startswith(f"reach     NOT RUNNABLE at G-code line {line}: "), shown
    _says_which_joint(reach[0], line)


def test_fabric_cli_plan_and_check_name_the_joint_its_angle_and_limit_and_the_line(session, settings, tmp_path):
    gcode, line = leaning_ring()
    path = tmp_path / "ring.gcode"
    path.write_bytes(gcode)
    planner = PlannerService(session, settings.cell, Cell.builtin(CELL_NAME), data_dir=tmp_path / "planner")
    planner.start()
    args = replace(settings, mode="client").to_args()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("planner",), deadline_s=WAIT_S)
        plan = subprocess.run([sys.executable, "-m", "fabric.cli.main", "plan", str(path), *args],
                              capture_output=True, text=True, timeout=WAIT_S)
        plan_json = subprocess.run([sys.executable, "-m", "fabric.cli.main", "plan", str(path), "--json", *args],
                                   capture_output=True, text=True, timeout=WAIT_S)
        check = subprocess.run([sys.executable, "-m", "fabric.cli.main", "check", str(path), *args],
                               capture_output=True, text=True, timeout=WAIT_S)
    finally:
        planner.close()
    assert plan.returncode == 2, plan.stderr
    shown = [ln for ln in plan.stdout.splitlines() if ln.startswith("NOT RUNNABLE")]
    assert len(shown) == 1 and "targets at joint limit: A5 " in shown[0], plan.stdout
    _says_which_joint(shown[0], line)
    fu = json.loads(plan_json.stdout)["summary"]["first_unreachable"]
    assert (fu["gcode_line"], fu["joint"], fu["limit_deg"]) == (line, 5, 115.0) and fu["value_deg"] > 115.0
    assert check.returncode != 0 and "error [unreachable]" in check.stderr, check.stderr
    _says_which_joint(check.stderr, line)
