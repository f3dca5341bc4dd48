"""Telemetry records (Parquet and CSV, sequence numbers and gaps), their plot, and the G-code preview."""
from __future__ import annotations

import numpy as np
import pytest

from fabric import schemas as s
from fabric.cli.main import main
from fabric.cli.record_cmds import gaps, read_table, sample_row, write_table

pytestmark = pytest.mark.timeout(120)


def rows_with_a_gap() -> list[dict]:
    rows = []
    for i, seq in enumerate((1, 2, 3, 6, 7)):           # pose samples 4 and 5 lost
        pose = s.Pose(seq=seq, t_sim_s=0.1 * seq, q_deg=[0.0] * 6, xyz_mm=[seq, 0.0, 1.0],
                      quat_wxyz=[1.0, 0, 0, 0], base_xyz_mm=[0.0] * 3)
        rows.append(sample_row("pose", pose, i + 1, 1000.0 + i))
        rows.append(sample_row("temps", s.Temps(nozzle_c=200.0 + i, nozzle_target_c=215.0, bed_c=60.0,
                                                bed_target_c=60.0, t_sim_s=0.1 * seq), i + 1, 1000.0 + i))
        rows.append(sample_row("extrusion", s.Extrusion(seq=i + 1, t_sim_s=0.1 * seq, on=i % 2 == 0, flow_mm3_s=3.0,
                                                        extruded_mm3=10.0 * i, filament_mm=4.0 * i, layer=0, row=i,
                                                        gcode_line=10 + i), i + 1, 1000.0 + i))
    rows.append(sample_row("events", s.Event(seq=9, t_sim_s=0.7, kind="paused", data={"reason": "operator"}), 1, 1.0))
    rows.append(sample_row("state", s.StationState(state="paused", t_sim_s=0.7, speed_r=1.5), 1, 1.0))
    return rows


@pytest.mark.parametrize("suffix", [".parquet", ".csv"])
def test_a_record_keeps_sequence_numbers_and_simulated_time(tmp_path, suffix):
    rows = rows_with_a_gap()
    path = tmp_path / f"rec{suffix}"
    write_table(rows, path)
    cols = read_table(path)
    pose = cols["topic"] == "pose"
    assert list(cols["seq"][pose]) == [1, 2, 3, 6, 7]
    assert list(cols["rx_seq"][pose]) == [1, 2, 3, 4, 5]
    assert np.allclose(cols["t_sim_s"][pose], [0.1, 0.2, 0.3, 0.6, 0.7])
    assert cols["seq"][cols["topic"] == "temps"].tolist() == [-1] * 5       # temps carry no publisher seq
    assert cols["kind"][cols["topic"] == "events"].tolist() == ["paused"]
    assert gaps(rows) == {"pose": 2}


def test_plot_and_preview_write_pictures(tmp_path, capsys):
    rec = tmp_path / "rec.csv"
    write_table(rows_with_a_gap(), rec)
    gcode = tmp_path / "square.gcode"
    lines = ["G21", "G90", "M82", "G92 E0"]
    for k in range(3):
        lines += [f";LAYER:{k}", f"G1 Z{0.3 * (k + 1):.1f} F600", "G1 X10 Y10 F3000"]
        lines += [f"G1 X{x} Y{y} E{(k * 4 + i + 1) * 0.5:.2f}" for i, (x, y) in
                  enumerate(((30, 10), (30, 30), (10, 30), (10, 10)))]
    gcode.write_text("\n".join(lines) + "\n")
    for args, png in ((["plot", str(rec)], tmp_path / "rec.png"),
                      (["preview", str(gcode), "--layer", "2"], tmp_path / "square.png")):
        assert main([*args, "-o", str(png)]) == 0
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["preview", str(gcode), "--layer", "9", "-o", str(tmp_path / "x.png")]) == 1
    assert "--layer counts from 1 to 3" in capsys.readouterr().err
