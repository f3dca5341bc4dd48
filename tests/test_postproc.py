"""Post-processors: the code they write is parsed back and checked against the program."""
from __future__ import annotations

import csv
import io
import re

import numpy as np
import pytest

from fabric.motion.program import MOVEJ, MOVEL, PRINT, RETRACT, WAIT_TEMP
from fabric.planning import PlanOptions, plan_gcode
from fabric.planning.post import (
    CSV_COLUMNS,
    RapidOptions,
    export_program,
    write_csv,
    write_export,
    write_krl,
    write_rapid,
    write_urscript,
)
from fabric.robot.cell import Cell
from fabric.robot.frames import R_from_quat, rot_x, rot_y, rot_z
from fabric.wire.errors import ValidationError


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


@pytest.fixture(scope="module")
def plan(cell: Cell):
    """A two-layer square spiral with retractions, heat-up and a few hundred targets."""
    lines = ["M104 S205", "M109 S205", "M83", "G1 Z5 F3000", ";LAYER_CHANGE", "G1 X60 Y60 Z0.3 F6000"]
    for layer in range(2):
        z = 0.3 + 0.3 * layer
        lines.append(f"G1 Z{z:.2f} F600")
        for k in range(60):
            r = 10 + k * 0.8
            for dx, dy in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
                lines.append(f"G1 X{125 + dx * r:.3f} Y{125 + dy * r:.3f} E{0.02 * r:.4f} F{1200 + 30 * k}")
        lines += ["G1 E-0.8 F2400", "G1 X60 Y60 F6000", "G1 E0.8 F2400", ";LAYER_CHANGE"]
    return plan_gcode("\n".join(lines) + "\n", cell, PlanOptions()).require_runnable()


def _moves(text: str) -> list[str]:
    return [ln.strip() for ln in text.splitlines() if re.match(r"\s*(MoveL|TriggL|MoveAbsJ)\b", ln)]


def test_rapid_modules_split_and_targets_round_trip(plan, cell: Cell) -> None:
    prog = plan.program
    out = io.StringIO()
    exp = write_rapid(prog, out, tool_T=cell.robot.tool_T, options=RapidOptions(targets_per_module=200))
    text = out.getvalue()
    modules = re.findall(r"^MODULE (\w+)\n(.*?)^ENDMODULE", text, flags=re.S | re.M)
    n_print = int(((prog.op <= MOVEL) & (prog.section == PRINT)).sum())
    assert [m[0] for m in modules] == exp.modules
    assert len(modules) == 1 + -(-n_print // 200)
    sizes = [len(_moves(body)) for _, body in modules[1:]]
    assert sizes == exp.targets[1:] and max(sizes) <= 200 and sum(sizes) == n_print
    # main calls every print procedure in order between Approach and ReturnHome
    calls = re.findall(r"^\s+(\w+);$", re.search(r"PROC main\(\)(.*?)ENDPROC", text, re.S).group(1), re.M)
    assert calls == ["ExtruderInit", "Approach"] + [f"Print_{k}" for k in range(1, len(sizes) + 1)] + ["ReturnHome"]
    # every robtarget is the planned plate-frame target; joint moves carry the planned joints
    moves = _moves(text)
    assert len(moves) == int((prog.op <= MOVEL).sum())
    lin = [m for m in moves if not m.startswith("MoveAbsJ")]
    xyz = np.array([[float(v) for v in re.search(r"\[\[([-\d.,]+)\],", m).group(1).split(",")] for m in lin])
    order = np.flatnonzero(prog.op == MOVEL)
    # main module (approach, return) is written first, then the print modules
    sec = prog.section[order]
    ordered = np.concatenate([order[sec != PRINT], order[sec == PRINT]])
    assert np.abs(xyz - prog.xyz_mm[ordered]).max() < 6e-4
    joints = [m for m in moves if m.startswith("MoveAbsJ")]
    q0 = np.array([float(v) for v in re.search(r"\[\[([-\d.,]+)\]", joints[0]).group(1).split(",")])
    assert np.allclose(q0, np.degrees(prog.q_rad[0]), atol=1e-4)
    # every speed / zone name used is declared
    used = set(re.findall(r", (v\w+), ", text)) | set(re.findall(r", (z\w+), ", text))
    declared = set(re.findall(r"CONST (?:speeddata|zonedata) (\w+)", text))
    assert used <= declared and used
    # extruder: on where the program starts extruding, off where it stops
    on, _ = prog.extruder_events()
    assert text.count("\\T2:=trOn") == len(on)
    # every extruding run is switched off once (by the next move, or before a stop); 2 are the procs' resets
    assert text.count("trOff\\T2:=trFlowOff") + text.count("SetDO doExtruder, 0;") - 2 == len(on)
    assert len(re.findall(r"^\s+Retract -?[\d.]+;$", text, re.M)) == int((prog.op == RETRACT).sum()) == 4
    assert text.count("WaitDI diNozzleAtTemp") == int((prog.op == WAIT_TEMP).sum())
    wobj = re.search(r"PERS wobjdata wobjPlate := \[FALSE,TRUE,\"\",\[\[([-\d.,]+)\]", text).group(1)
    assert np.allclose([float(v) for v in wobj.split(",")], prog.wobj[:3, 3])
    tool = re.search(r"PERS tooldata tExtruder := \[TRUE,\[\[([-\d.,]+)\]", text).group(1)
    assert np.allclose([float(v) for v in tool.split(",")], cell.robot.tool_T[:3, 3])


def test_rapid_one_stream_per_module(plan) -> None:
    files: dict[str, io.StringIO] = {}

    def sink(name: str) -> io.StringIO:
        files[name] = io.StringIO()
        return files[name]

    exp = write_rapid(plan.program, sink, options=RapidOptions(targets_per_module=500, prefix="P"))
    assert list(files) == exp.modules and exp.modules[0] == "PMain"
    for name, f in files.items():
        text = f.getvalue()
        assert text.startswith(f"MODULE {name}\n") and text.rstrip().endswith("ENDMODULE")
    with pytest.raises(ValidationError):
        RapidOptions(targets_per_module=0)
    with pytest.raises(ValidationError):
        RapidOptions(tool_name="1bad name")


def _zyx(a: float, b: float, c: float) -> np.ndarray:
    return rot_z(np.radians(a)) @ rot_y(np.radians(b)) @ rot_x(np.radians(c))


def test_krl_targets_and_frames(plan, cell: Cell) -> None:
    prog = plan.program
    src, dat = io.StringIO(), io.StringIO()
    n = write_krl(prog, src, dat, tool_T=cell.robot.tool_T)
    s = src.getvalue()
    lins = re.findall(r"LIN \{X ([-\d.]+),Y ([-\d.]+),Z ([-\d.]+),A ([-\d.]+),B ([-\d.]+),C ([-\d.]+)\}", s)
    ptps = re.findall(r"PTP \{([^}]*)\}", s)
    assert len(lins) == int((prog.op == MOVEL).sum()) and len(ptps) == int((prog.op == MOVEJ).sum())
    assert n == len(lins) + len(ptps)
    vals = np.array(lins, dtype=float)
    lin_rows = np.flatnonzero(prog.op == MOVEL)
    assert np.abs(vals[:, :3] - prog.xyz_mm[lin_rows]).max() < 6e-4
    R = np.array([_zyx(*v) for v in vals[:50, 3:]])
    assert np.abs(R - R_from_quat(prog.quat_wxyz[lin_rows[:50]])).max() < 1e-5
    base = re.search(r"AM_BASE=\{X ([-\d.]+),Y ([-\d.]+),Z ([-\d.]+)", dat.getvalue()).groups()
    assert np.allclose(np.array(base, float), prog.wobj[:3, 3])
    assert s.count("DO $OUT[1]=TRUE") == len(prog.extruder_events()[0])
    assert s.startswith("&ACCESS") and s.rstrip().endswith("END")


def _rotvec_R(rv: np.ndarray) -> np.ndarray:
    th = np.linalg.norm(rv)
    k = rv / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def test_urscript_poses_in_metres_and_radians(plan) -> None:
    prog = plan.program
    out = io.StringIO()
    write_urscript(prog, out)
    s = out.getvalue()
    movel = re.findall(r"movel\(pose_trans\(plate, p\[([-\d.,]+)\]\), a=[\d.]+, v=([\d.]+), r=([\d.]+)\)", s)
    movej = re.findall(r"movej\(\[([-\d.,]+)\]", s)
    lin_rows = np.flatnonzero(prog.op == MOVEL)
    assert len(movel) == len(lin_rows) and len(movej) == int((prog.op == MOVEJ).sum())
    p = np.array([m[0].split(",") for m in movel], dtype=float)
    assert np.abs(p[:, :3] * 1000.0 - prog.xyz_mm[lin_rows]).max() < 1e-3
    assert np.allclose(np.array([m[1] for m in movel], float) * 1000.0, prog.speed_mm_s[lin_rows], atol=0.01)
    R = np.array([_rotvec_R(v) for v in p[:40, 3:]])
    assert np.abs(R - R_from_quat(prog.quat_wxyz[lin_rows[:40]])).max() < 1e-5
    q = np.array(movej[0].split(","), dtype=float)
    assert np.allclose(q, prog.q_rad[0], atol=1e-6)
    assert s.rstrip().endswith("am_print()")


def test_csv_columns_rows_and_times(plan, cell: Cell) -> None:
    from fabric.motion.timing import StartState, time_program
    prog = plan.program
    tl = time_program(prog, cell.robot, 1.0, start_state=StartState.at_joints(cell.robot, prog.wobj, cell.home_q_rad))
    out = io.StringIO()
    n = write_csv(prog, out, tl.t_end_s)
    rows = list(csv.reader(io.StringIO(out.getvalue())))
    assert rows[0] == CSV_COLUMNS == ["gcode_line", "x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz", "q1_deg",
                                      "q2_deg", "q3_deg", "q4_deg", "q5_deg", "q6_deg", "speed_mm_s", "extrude", "t_s"]
    data = np.array(rows[1:], dtype=float)
    motion = np.flatnonzero(prog.op <= MOVEL)
    assert n == len(data) == len(motion)
    assert np.array_equal(data[:, 0], prog.gcode_line[motion])
    assert np.abs(data[:, 1:4] - prog.xyz_mm[motion]).max() < 1e-4
    assert np.abs(data[:, 8:14] - np.degrees(prog.q_rad[motion])).max() < 1e-5
    assert np.array_equal(data[:, 15], (prog.flow_mm3_mm[motion] > 0).astype(float))
    assert np.all(np.diff(data[:, 16]) >= 0) and np.isclose(data[-1, 16], tl.total_s, atol=1e-4)
    out2 = io.StringIO()
    write_csv(prog, out2)
    assert out2.getvalue().splitlines()[1].endswith(",")          # no timeline: empty t_s


def test_export_program_files(plan, cell: Cell, tmp_path) -> None:
    prog = plan.program
    files = export_program(prog, "rapid", tmp_path / "rapid", tool_T=cell.robot.tool_T,
                           rapid=RapidOptions(targets_per_module=300))
    pgf = files[0].read_text()
    mods = re.findall(r"<Module>(\w+)\.mod</Module>", pgf)
    targets = int((prog.op <= MOVEL).sum())
    assert [f.stem for f in files[1:]] == mods and mods[0] == "AMMain" and len(mods) == 1 + -(-targets // 300) > 2
    n = sum(len(_moves(f.read_text())) for f in files[1:])
    assert n == targets
    src, dat = export_program(prog, "krl", tmp_path / "krl")
    assert src.suffix == ".src" and "DEFDAT am_print" in dat.read_text()
    (script,) = export_program(prog, "urscript", tmp_path / "p.script")
    assert script.read_text().count("movel(") == int((prog.op == MOVEL).sum())
    (table,) = export_program(prog, "csv", tmp_path / "p.csv")
    assert len(table.read_text().splitlines()) == 1 + int((prog.op <= MOVEL).sum())
    with pytest.raises(ValidationError):
        export_program(prog, "gcode", tmp_path / "x")


def test_write_export_single_stream(plan, cell: Cell) -> None:
    prog = plan.program
    for fmt, count in (("rapid", r"^\s+(?:MoveL|TriggL|MoveAbsJ) "), ("krl", r"^\s+(?:LIN|PTP) "),
                       ("urscript", r"^\s+move[lj]\("), ("csv", r"^-?\d+,")):
        out = io.StringIO()
        write_export(prog, fmt, out, cell, module_targets=250)
        assert len(re.findall(count, out.getvalue(), re.M)) == int((prog.op <= MOVEL).sum()), fmt
    out = io.StringIO()
    write_export(prog, "krl", out, cell)
    assert "$BASE={X 475.000" in out.getvalue() and "AM_BASE" not in out.getvalue()


@pytest.mark.parametrize("window_rows", [7, 64, 1_000_000])
def test_rapid_text_is_the_same_whatever_the_formatting_windows(plan, cell: Cell, monkeypatch, window_rows) -> None:
    """MoveL lines come from aligned windows formatted ahead on worker threads; runs that span two
    windows, or many, give the same text as one window over everything."""
    from fabric.planning.post import rapid

    def text() -> str:
        out = io.StringIO()
        write_rapid(plan.program, out, tool_T=cell.robot.tool_T, options=RapidOptions(targets_per_module=50))
        return out.getvalue()
    monkeypatch.setattr(rapid, "MOVEL_TEXT_ROWS", 10_000_000)
    whole = text()
    monkeypatch.setattr(rapid, "MOVEL_TEXT_ROWS", window_rows)
    assert text() == whole


def test_ordered_map_keeps_order_bounds_work_in_flight_and_raises_where_it_failed() -> None:
    import threading
    import time

    from fabric.ahead import ordered_map
    running, peak, lock = [0], [0], threading.Lock()

    def slow_square(k: int) -> int:
        with lock:
            running[0] += 1
            peak[0] = max(peak[0], running[0])
        time.sleep(0.002 * (k % 3))                 # finishing out of order
        with lock:
            running[0] -= 1
        if k == 7:
            raise ValueError("block 7")
        return k * k
    got = []
    with pytest.raises(ValueError, match="block 7"):
        for v in ordered_map(slow_square, range(20), workers=2, ahead=3):
            got.append(v)
    assert got == [k * k for k in range(7)] and peak[0] <= 2
    assert list(ordered_map(lambda k: -k, iter([]))) == []
