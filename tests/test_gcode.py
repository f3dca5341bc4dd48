"""G-code interpreter: dialect features on hand-written snippets, and real slicer output."""
from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from fabric.gcode import (
    EV_BED_TEMP,
    EV_DWELL,
    EV_EXTRUDE,
    EV_FAN,
    EV_FW_RETRACT,
    EV_FW_UNRETRACT,
    EV_NOZZLE_TEMP,
    WAIT_ANY,
    WAIT_HEAT,
    WAIT_NONE,
    parse_gcode,
    parse_gcode_file,
)
from fabric.gcode.lexer import W_BAD, W_EMPTY, W_OK, lex_block
from fabric.wire.errors import GcodeError, ValidationError


def tp_of(text: str, **kw):
    return parse_gcode(text, **kw)


# -- lexer ----------------------------------------------------------------

def test_numbers_parse_exactly_like_float() -> None:
    rng = np.random.default_rng(3)
    toks = [f"{v:.{d}f}" for v, d in zip(rng.uniform(-1e5, 1e5, 3000), rng.integers(0, 9, 3000), strict=True)]
    toks += [".5", "-.25", "+3.", "007", "123456789012.345", "0.000000000001", "12345678901234567.5"]
    lx = lex_block(" ".join("X" + t for t in toks).encode())
    assert (lx.word_status == W_OK).all()
    assert lx.word_value.tolist() == [float(t) for t in toks]


def test_lexer_flags_malformed_and_empty_values() -> None:
    lx = lex_block(b"G1 X1.2.3 Y-\nG1 Z- E\nG1 X1+2 Y.\n")
    assert lx.word_status[1:3].tolist() == [W_BAD, W_BAD]
    assert lx.word_status[4:6].tolist() == [W_BAD, W_EMPTY]
    assert lx.word_status[7:9].tolist() == [W_BAD, W_BAD]


# -- motion and modes -----------------------------------------------------

def test_linear_moves_modal_feed_and_absolute_e() -> None:
    tp = tp_of("G21\nG90\nM82\nG92 E0\nG1 X10 Y0 E1 F1200\nG1 X10 Y5 E1.5\nG0 X0 Y0 F6000\nG1 F600\nG1 Z1\n")
    assert tp.xyz_mm.tolist() == [[10, 0, 0], [10, 5, 0], [0, 0, 0], [0, 0, 1]]
    assert tp.e_mm.tolist() == [1.0, 0.5, 0.0, 0.0]
    assert tp.feed_mm_s.tolist() == [20.0, 20.0, 100.0, 10.0]
    assert tp.line.tolist() == [5, 6, 7, 9]
    assert tp.start_xyz_mm.tolist() == [0, 0, 0]


def test_relative_xyz_and_relative_e_and_g90_resets_e() -> None:
    tp = tp_of("G91\nG1 X5 Y5 E2 F600\nG1 X5 E1\nG90\nG1 X20 E5\nM83\nG1 X21 E0.5\n")
    assert tp.xyz_mm[:, :2].tolist() == [[5, 5], [10, 5], [20, 5], [21, 5]]
    # G91 makes E relative too; G90 makes it absolute (E was at 3): 5 - 3 = 2
    assert tp.e_mm.tolist() == [2.0, 1.0, 2.0, 0.5]


def test_g92_offsets_and_homing() -> None:
    tp = tp_of("G1 X100 Y50 F600\nG92 X0 Y0\nG1 X10\nG92 E5\nG1 X11 E6\nG28 X\nG1 Y1\nG92\nG1 X1\n")
    assert tp.xyz_mm[:, :2].tolist() == [[100, 50], [110, 50], [111, 50], [0, 51], [1, 51]]
    assert tp.e_mm.tolist() == [0, 0, 1.0, 0, 0]


def test_inches() -> None:
    tp = tp_of("G20\nG1 X1 Y2 E0.1 F60\nG21\nG1 X1\n")
    assert np.allclose(tp.xyz_mm[0], [25.4, 50.8, 0])
    assert np.isclose(tp.e_mm[0], 2.54)
    assert np.isclose(tp.feed_mm_s[0], 25.4)
    assert np.allclose(tp.xyz_mm[1], [1, 50.8, 0])


def test_arc_ij_within_chord_tolerance_and_exact_end() -> None:
    tol = 0.01
    tp = tp_of("G1 X10 Y0 F600\nG3 X0 Y10 I-10 J0 E2\n", chord_tol_mm=tol)
    pts = tp.xyz_mm[1:]
    r = np.hypot(pts[:, 0], pts[:, 1])
    assert np.allclose(r, 10.0)
    assert pts[-1].tolist() == [0.0, 10.0, 0.0]
    mids = 0.5 * (np.vstack([[10, 0, 0], pts[:-1]]) + pts)
    sag = 10.0 - np.hypot(mids[:, 0], mids[:, 1])
    assert sag.max() <= tol + 1e-12 and sag.max() > tol / 4        # tight, not wasteful
    ang = np.arctan2(pts[:, 1], pts[:, 0])
    assert (np.diff(ang) > 0).all()                                 # G3 is counter-clockwise
    assert np.isclose(tp.e_mm[1:].sum(), 2.0)
    assert (tp.line[1:] == 2).all()


def test_arc_clockwise_r_form_and_full_circle() -> None:
    tp = tp_of("G1 X0 Y0 F600\nG2 X10 Y0 R5\n")          # CW minor arc over the top: centre (5, 0)
    pts = tp.xyz_mm[1:]
    assert np.allclose(np.hypot(pts[:, 0] - 5, pts[:, 1]), 5)
    assert (pts[:-1, 1] > 0).all()
    tp = tp_of("G1 X0 Y0 F600\nG2 X10 Y0 R-7\n")         # major arc: more than half a circle
    pts = np.vstack([[0, 0, 0], tp.xyz_mm[1:]])
    length = np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()
    assert length > np.pi * 7
    tp = tp_of("G1 X5 Y0 F600\nG2 X5 Y0 I-5 J0 Z1\n")     # full circle (helix)
    pts = tp.xyz_mm[1:]
    assert np.allclose(np.hypot(pts[:, 0], pts[:, 1]), 5)
    assert np.isclose(pts[-1, 2], 1.0) and len(pts) >= 50


@pytest.mark.parametrize("text, line, what", [
    ("G1 X1\nG2 X5 Y5\n", 2, "no centre"),
    ("G1 X1\nG1 X1.2.3\n", 2, "malformed"),
    ("G1 X1\n\nG1 Xabc Y2\n", 3, "no value"),
    ("G0 X2\nG1 Y\n", 2, "no value"),
    ("G1 X1 -5\n", 1, "unexpected text"),
    ("G1 X ; 5\n", 1, "no value"),
    ("G1 X1\nG1 X1e30\n", 2, "exponent form"),
    ("G1 X1 E2.5E3\n", 1, "exponent form"),
    ("G1 X1 X2\n", 1, "X appears twice"),
    ("G1 X1\nG1 X2 E1 Y2 e3\n", 2, "E appears twice"),
    ("G90 G21\n", 1, "G appears twice"),
    ("N7 G1 X1 x2\n", 1, "X appears twice"),
    ("G1 X1\nG3 X10 Y0 R2\n", 2, "smaller than half"),
    ("G1 F0\n", 1, "feed"),
    ("G1 X1\nG1.2.3 X4\n", 2, "malformed command"),
    ("G2 X0 Y0 I0 J0\n", 1, "zero radius"),
    ("G1 X1 F600\nG2 X2 Y0 I5 J0\n", 2, "not on the arc"),
])
def test_malformed_known_commands_raise_with_line(text: str, line: int, what: str) -> None:
    with pytest.raises(GcodeError) as ei:
        tp_of(text)
    assert ei.value.details["line"] == line
    assert what in str(ei.value)
    assert ei.value.details["text"]


def test_what_senders_and_controllers_write_is_read_as_they_read_it() -> None:
    """Lowercase, blanks between letter and number, line numbers, checksums, both comment styles."""
    plain = tp_of("G21\nG90\nM83\nG1 X10 Y5 Z0.3 F1200\nG1 X20 Y5 E0.8\nG28 X Y\nG1 X3 Y4\n")
    numbered = [f"N{i} {cmd}" for i, cmd in enumerate(["G21", "G90", "M83"], 1)]
    styled = tp_of("\n".join(f"{line}*{_checksum(line)}" for line in numbered) + "\n"
                   "g1 x 10 y 5 z .3 f 1200 ; first point\n"
                   "G 1 (to the right) X20\tY5 E+0.8\r\n"
                   "G28 X Y\n"
                   "N 9 G1 X3 Y4 ; X9\n")
    for name in ("xyz_mm", "e_mm", "feed_mm_s", "line"):
        assert np.array_equal(getattr(plain, name), getattr(styled, name)), name


def test_unknown_commands_are_counted_not_fatal() -> None:
    tp = tp_of("M117 Printing... X1.2.3\nM84\nM84\nT0\nG29.1\nG1 X1 F60\nHELLO\n")
    assert tp.unknown_commands == {"G29.1": 1, "H": 1, "M117": 1, "M84": 2, "T0": 1}
    assert len(tp) == 1


def test_comments_and_checksums() -> None:
    tp = tp_of("G1 X1 F60 ; go X9\n(whole line X7)\nG1 (inline Y5) Y2\nN12 G1 X3*" +
               str(_checksum("N12 G1 X3")) + "\n")
    assert tp.xyz_mm[:, :2].tolist() == [[1, 0], [1, 2], [3, 2]]
    with pytest.raises(GcodeError) as ei:
        tp_of("G1 X1\nN13 G1 X3*1\n")
    assert ei.value.details["line"] == 2 and "checksum" in str(ei.value)


def _checksum(s: str) -> int:
    c = 0
    for ch in s.encode():
        c ^= ch
    return c


def test_events_temperatures_fan_dwell_retraction() -> None:
    tp = tp_of("M140 S60\nM104 S200\nM190 S60\nM109 R190\nM106 S127.5\nG1 X1 F60\nG4 P500\n"
               "G10\nG1 X2\nG11\nG4 S2\nM107\nM109 S210\nG1 E-1\nG1 X3\n")
    kinds = tp.event_kind.tolist()
    assert kinds == [EV_BED_TEMP, EV_NOZZLE_TEMP, EV_BED_TEMP, EV_NOZZLE_TEMP, EV_FAN, EV_DWELL,
                     EV_FW_RETRACT, EV_FW_UNRETRACT, EV_DWELL, EV_FAN, EV_NOZZLE_TEMP, EV_EXTRUDE]
    assert tp.event_aux[:4].tolist() == [WAIT_NONE, WAIT_NONE, WAIT_HEAT, WAIT_ANY]
    assert tp.event_value.tolist() == [60, 200, 60, 190, 0.5, 0.5, 0, 0, 2.0, 0, 210, -1.0]
    assert tp.event_row.tolist() == [0, 0, 0, 0, 0, 1, 1, 2, 2, 2, 2, 2]
    assert tp.event_line.tolist() == [1, 2, 3, 4, 5, 7, 8, 10, 11, 12, 13, 14]


def test_blocks_carry_state_exactly() -> None:
    lines = ["G21", "G90", "M83", "G92 E0", ";LAYER:0", ";TYPE:WALL-OUTER"]
    rng = np.random.default_rng(0)
    for i in range(3000):
        if i % 500 == 0:
            lines += [f";LAYER:{i // 500 + 1}", "G91", "G1 Z0.2", "G90", ";TYPE:FILL"]
        x, y, e = rng.uniform(0, 200), rng.uniform(0, 200), rng.uniform(0, 1)
        lines.append(f"G1 X{x:.3f} Y{y:.3f} E{e:.4f} F{rng.integers(600, 3000)}")
        if i % 97 == 0:
            lines += ["G91", "G3 X10 Y0 I5 J0", "G90", "G92 X0", "M104 S205"]
    text = "\n".join(lines) + "\n"
    whole = tp_of(text)
    small = tp_of(text, block_bytes=1024)
    for name in ("xyz_mm", "e_mm", "feed_mm_s", "line", "layer", "feature", "event_row", "event_line"):
        assert np.array_equal(getattr(whole, name), getattr(small, name)), name
    assert whole.n_layers == small.n_layers == 6      # ;LAYER:0 + ;LAYER:1 with no move between: one
    assert whole.feature_names == ["none", "WALL-OUTER", "FILL"]


def test_dialect_layer_and_feature_markers() -> None:
    prusa = ";LAYER_CHANGE\n;Z:0.2\n;HEIGHT:0.2\nG1 Z.2 F600\n;TYPE:Perimeter\nG1 X1 E1\n" \
            ";LAYER_CHANGE\n;Z:0.4\nG1 Z.4\n;TYPE:External perimeter\nG1 X2 E1\n"
    tp = tp_of(prusa)
    assert tp.layer.tolist() == [0, 0, 1, 1] and tp.layer_z_mm.tolist() == [0.2, 0.4]
    assert [tp.feature_names[f] for f in tp.feature] == ["none", "Perimeter", "Perimeter", "External perimeter"]
    cura = (";FLAVOR:Marlin\nG1 Z5 F600\n;LAYER:-1\n;TYPE:SKIRT\nG1 Z0.3\nG1 X1 E1\n"
            ";LAYER:0\n;TYPE:WALL-OUTER\nG1 Z0.5\nG1 X2 E2\n")
    tp = tp_of(cura)
    assert tp.layer.tolist() == [-1, 0, 0, 1, 1] and tp.layer_z_mm.tolist() == [0.3, 0.5]
    assert tp.slicer == "cura"
    s3d = "; G-Code generated by Simplify3D(R)\n; layer 1, Z = 0.250\n; feature outer perimeter\n" \
          "G1 Z0.25 F600\nG1 X1 E1\n" \
          "; layer 2, Z = 0.500\n; feature solid layer\nG1 Z0.5\nG1 X2 E1\n"
    tp = tp_of(s3d)
    assert tp.layer.tolist() == [0, 0, 1, 1] and tp.layer_z_mm.tolist() == [0.25, 0.5]
    assert tp.feature_names[1:] == ["outer perimeter", "solid layer"]
    # Slic3r without markers: layers from Z increases of extruding moves (z-hops ignored)
    slic3r = "M83\nG1 Z5 F600\nG1 Z0.3\nG1 X1 E1\nG1 Z0.7\nG1 X5\nG1 Z0.3\nG1 X2 E1\nG1 Z0.6\nG1 X3\nG1 X4 E1\n"
    tp = tp_of(slic3r)
    assert tp.layer.tolist() == [-1, -1, 0, 0, 0, 0, 0, 1, 1, 1]
    assert tp.layer_z_mm.tolist() == [0.3, 0.6]


def test_duplicate_layer_markers_count_once() -> None:
    tp = tp_of(";LAYER_CHANGE\n;LAYER:0\nG1 Z0.2 X1 E1 F600\n;LAYER_CHANGE\n;LAYER:1\nG1 Z0.4 X2 E1\n")
    assert tp.layer.tolist() == [0, 1] and tp.n_layers == 2


def test_file_and_memory_give_the_same_toolpath(tmp_path: Path) -> None:
    text = "G1 X1 Y1 F600\r\nG1 X2 E1\r\nG2 X4 Y1 I1 J0\r\nM104 S200"
    p = tmp_path / "a.gcode"
    p.write_text(text)
    a, b = parse_gcode_file(p), tp_of(text)
    assert np.array_equal(a.xyz_mm, b.xyz_mm) and a.n_lines == b.n_lines == 4
    assert a.event_line.tolist() == [4]
    with pytest.raises(ValidationError):
        tp_of(text, chord_tol_mm=0)


def test_empty_and_comment_only_input() -> None:
    assert len(tp_of("")) == 0
    tp = tp_of("; nothing\n\n")
    assert len(tp) == 0 and tp.n_lines == 2 and tp.n_layers == 0


# -- real slicer output -----------------------------------------------------

def _box_stl(path: Path, size: float = 20.0) -> Path:
    import trimesh
    mesh = trimesh.creation.box((size, size, size))
    mesh.apply_translation((0, 0, size / 2))
    mesh.export(path)
    return path


@pytest.mark.slicers
@pytest.mark.parametrize("binary", ["prusa-slicer", "slic3r"])
def test_real_slicer_files(tmp_path: Path, binary: str) -> None:
    exe = shutil.which(binary)
    if exe is None:
        pytest.skip(f"{binary} not installed")
    stl = _box_stl(tmp_path / "box.stl")
    out = tmp_path / "box.gcode"
    args = [exe, "--export-gcode", str(stl), "-o", str(out)] if binary == "prusa-slicer" \
        else [exe, str(stl), "-o", str(out)]
    subprocess.run(args, check=True, capture_output=True, timeout=60)
    text = out.read_text()
    tp = parse_gcode_file(out)
    # layers: first layer height then layer_height up to the top of the 20 mm box
    assert 60 <= tp.n_layers <= 70
    assert np.isclose(tp.layer_z_mm[0], 0.35)
    assert np.all(np.diff(tp.layer_z_mm) > 0)
    assert 19.5 <= tp.layer_z_mm[-1] <= 20.2
    ext = tp.extruding()
    assert np.allclose(tp.xyz_mm[ext, 2], tp.layer_z_mm[tp.layer[ext]])
    # filament: the slicer's own figure
    m = re.search(r"filament used \[mm\] = ([\d.]+)|Filament required: ([\d.]+)mm", text) or \
        re.search(r"; filament used = ([\d.]+)mm", text)
    if m is not None:
        used = float(next(g for g in m.groups() if g))
        assert abs(tp.deposited_filament_mm() - used) < 0.1
    # the extruded moves stay on the box's footprint (+ skirt): a 20 mm square near the bed centre
    xy = tp.xyz_mm[ext, :2]
    assert np.ptp(xy[tp.layer[ext] > 2], axis=0).max() <= 20.5
    assert tp.unknown_commands.get("M84") == 1


def test_lexing_ahead_on_a_worker_gives_what_one_thread_gives(monkeypatch) -> None:
    """Files are lexed a block ahead by a worker thread: with tiny blocks (many hand-overs), rows,
    events, unknown commands and the error of a bad line are those of the plain one-thread walk."""
    import fabric.gcode.reader as reader
    from fabric.gcode.interp import lex_and_tabulate
    lines = ["M83", "G28", "G1 Z0.3 F600", "M117 hi", "G1 X10 Y10 E0.5 F1200"]
    lines += [f"G1 X{10 + k % 17} Y{10 + k % 11} E0.02" + (" ; note" if k % 5 == 0 else "") for k in range(3000)]
    lines += ["M999", "G92 E0", "G1 X1 Y1 E1"]
    text = "\n".join(lines) + "\n"
    threaded = parse_gcode(text, block_bytes=1024)
    monkeypatch.setattr(reader, "lexed_blocks", lambda blocks: map(lex_and_tabulate, blocks))
    plain = parse_gcode(text, block_bytes=1024)
    for name in ("xyz_mm", "e_mm", "feed_mm_s", "line", "event_row", "event_kind", "event_value"):
        assert np.array_equal(getattr(threaded, name), getattr(plain, name)), name
    assert len(threaded) > 3000 and threaded.unknown_commands == plain.unknown_commands
    assert threaded.unknown_commands == {"M117": 1, "M999": 1}
    bad = text.replace("G1 X12 Y12 E0.02\n", "G1 X12 Y1Q E0.02\n", 1)
    monkeypatch.undo()
    with pytest.raises(GcodeError) as err:
        parse_gcode(bad, block_bytes=1024)
    assert err.value.details["line"] == bad.splitlines().index("G1 X12 Y1Q E0.02") + 1
