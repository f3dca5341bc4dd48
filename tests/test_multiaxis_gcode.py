"""The multi-axis G-code dialect: the reader's nozzle axes, typed errors, turn splitting, and fuzzing."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fabric.gcode import ToolpathChunks, parse_gcode
from fabric.gcode.toolpath import EV_NOZZLE_TEMP
from fabric.planning.turns import split_turns, turn_angles_rad
from fabric.wire.errors import GcodeError

HEAD = "; multiaxis: nozzle axis in I J K\nG21\nG90\nM83\n"


def _ring(n: int = 24, tilt_deg: float = 30.0, radius: float = 10.0, z: float = 2.0) -> str:
    """A ring of extruding moves whose nozzle leans outwards by ``tilt_deg`` (axis from the tip up)."""
    lines = [HEAD + ";LAYER_CHANGE\n;Z:2\nM104 S210\n"]
    t = math.radians(tilt_deg)
    for k in range(n + 1):
        a = 2 * math.pi * k / n
        x, y = 50 + radius * math.cos(a), 50 + radius * math.sin(a)
        i, j, kk = math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)
        cmd = "G0" if k == 0 else "G1"
        e = "" if k == 0 else " E0.05"
        lines.append(f"{cmd} X{x:.4f} Y{y:.4f} Z{z} I{i:.6f} J{j:.6f} K{kk:.6f}{e} F1200\n")
    return "".join(lines)


def test_the_dialect_gives_every_row_its_unit_axis() -> None:
    tp = parse_gcode(_ring())
    assert tp.multiaxis and tp.axis is not None and tp.axis.shape == (len(tp), 3)
    np.testing.assert_allclose(np.linalg.norm(tp.axis, axis=1), 1.0, atol=1e-12)
    tilt = np.degrees(np.arccos(tp.axis[:, 2]))
    np.testing.assert_allclose(tilt, 30.0, atol=1e-3)
    # the axis points away from the ring's centre, like the position
    radial = tp.xyz_mm[:, :2] - 50.0
    assert np.all(np.einsum("ij,ij->i", radial, tp.axis[:, :2]) > 0)
    # planar G-code has no axes
    assert parse_gcode("G21\nG90\nG1 X1 Y1 Z1 I1 J0 F100\n").axis is None


def test_axis_letters_are_modal_and_normalised() -> None:
    tp = parse_gcode(HEAD + "G1 X1 Y0 Z1 I0 J0 K2 E1 F600\nG1 X2 I1\nG1 X3\nG1 I0 J1 K0\nG1 X4\n")
    # K2 is (0, 0, 1); then I1 keeps K2: (1, 0, 2)/sqrt5; the next move keeps it; an axis-only move turns it
    # for the move after it
    np.testing.assert_allclose(tp.axis[0], [0, 0, 1])
    np.testing.assert_allclose(tp.axis[1], np.array([1, 0, 2]) / math.sqrt(5))
    np.testing.assert_allclose(tp.axis[2], tp.axis[1])
    np.testing.assert_allclose(tp.axis[3], [0, 1, 0])
    assert len(tp) == 4


def test_a_zero_axis_and_arcs_are_errors_naming_their_line() -> None:
    with pytest.raises(GcodeError, match="zero vector") as exc:
        parse_gcode(HEAD + "G1 X1 Y1 Z1 I0 J0 K1 E1 F600\nG1 X2 I0 J0 K0 E1\n")
    assert exc.value.details["line"] == 6
    with pytest.raises(GcodeError, match="arc") as exc:
        parse_gcode(HEAD + "G1 X1 Y1 Z1 I0 J0 K1 F600\nG2 X5 Y1 I2 J0\n")
    assert exc.value.details["line"] == 6


def test_chunks_carry_the_axes_like_the_whole_file() -> None:
    text = "".join(_ring(n=400, z=2.0 + 0.3 * k).replace(HEAD, "") if k else _ring(n=400) for k in range(6))
    whole = parse_gcode(text)
    parts = [tp for tp, _last in ToolpathChunks(text.encode(), chunk_rows=300, block_bytes=2048)]
    assert len(parts) > 2
    assert all(tp.axis is not None for tp in parts)
    np.testing.assert_array_equal(np.concatenate([tp.axis for tp in parts]), whole.axis)
    np.testing.assert_array_equal(np.concatenate([tp.xyz_mm for tp in parts]), whole.xyz_mm)


def test_split_turns_cuts_big_turns_into_equal_pieces() -> None:
    text = HEAD + "M104 S200\nG1 X0 Y0 Z1 I0 J0 K1 E0.1 F600\nM104 S205\nG0 X10 Y0 Z1 I1 J0 K1\nG1 X11 E0.4\n"
    tp = parse_gcode(text)
    out = split_turns(tp, 5.0, prev_axis=np.array([0.0, 0.0, 1.0]))
    # the travel turns 45 deg: 9 pieces; the others are kept
    assert len(out) == len(tp) + 8
    assert np.degrees(turn_angles_rad(out.axis, np.array([0.0, 0.0, 1.0]))).max() <= 5.0 + 1e-9
    np.testing.assert_allclose(out.xyz_mm[-1], tp.xyz_mm[-1])
    np.testing.assert_allclose(out.xyz_mm[1:10, 1], 0.0)                   # along the straight segment
    np.testing.assert_allclose(np.linalg.norm(out.axis, axis=1), 1.0, atol=1e-12)
    assert out.e_mm.sum() == pytest.approx(tp.e_mm.sum())
    assert set(out.line.tolist()) == set(tp.line.tolist())
    # the event before the travel now precedes its first piece
    rows, values, _ = out.events_of(EV_NOZZLE_TEMP)
    assert rows.tolist() == [0, 1] and values.tolist() == [200.0, 205.0]
    # nothing to split: the same object back
    assert split_turns(tp, 90.0) is tp
    assert split_turns(parse_gcode("G1 X1 Y1 Z1 F100\n"), 1.0).axis is None


ALPHABET = "GMXYZEFIJKR0123456789.-+ ;\n"
FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FAST
@given(st.text(alphabet=ALPHABET, max_size=300))
def test_garbled_multiaxis_text_parses_or_names_a_line(text: str) -> None:
    data = HEAD + text
    n_lines = data.count("\n") + 1
    try:
        tp = parse_gcode(data)
    except GcodeError as exc:
        assert 1 <= exc.details["line"] <= n_lines
        return
    assert tp.axis is not None and tp.axis.shape == (len(tp), 3)
    if len(tp):
        assert np.isfinite(tp.axis).all()
        np.testing.assert_allclose(np.linalg.norm(tp.axis, axis=1), 1.0, atol=1e-9)
