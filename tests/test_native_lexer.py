"""The G-code lexer in C gives the numpy lexer's arrays, byte for byte, on real, edge-case and fuzzed text."""
from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import fabric
from fabric.gcode import native_lexer
from fabric.gcode.lexer import Lexed, lex_block, lex_block_numpy
from fabric.slicing import load_profile, slice_model

pytestmark = pytest.mark.skipif(not native_lexer.available(), reason="the C lexer is not built here")


def same(block: bytes) -> None:
    """Every field of the C lexer's result equals the numpy lexer's (dtype, shape, values, NaNs, signs of 0)."""
    got, want = lex_block(block), lex_block_numpy(block)
    for f in dataclasses.fields(Lexed):
        a, b = getattr(got, f.name), getattr(want, f.name)
        if f.name == "n_lines":
            assert a == b, (f.name, block)
            continue
        assert a.dtype == b.dtype and a.shape == b.shape, (f.name, a.dtype, b.dtype, a.shape, b.shape, block)
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), (f.name, a, b, block)
        if a.dtype.kind == "f":
            assert np.array_equal(np.signbit(a), np.signbit(b)), (f.name, block)


EDGES = [
    b"G1 X1 Y2\n", b"G1 X1 Y2", b"N10 G1 X5*12\n", b"N10 G1 X5*99\n", b"G1 X 5 Y\n", b"G 1 X\t 5\n",
    b"5 G1\n", b"G1 X1e30\n", b"G1 X1 E5\nG1 X1E5\nG1 X1.E5\n", b"G1 (a;b*c) X2 ; note X9\n",
    b"G1 X1\r\nG1 Y2\rG1 Z3", b"G1 X-.5 Y+3. Z.\n", b"G1 X-0\n", b"G1 X12345678901234567890.5\n",
    b"G1 X1" + b"0" * 400 + b"\n", b"G1 X1.2.3\n", b"*\n", b";\n", b"N1 N2 G1\n", b"G1 X1)\n(", b"(((\n)))\n",
    b"\n\n", b"\r\r\n", b"G28 X Y\n", b"M117 hello 5\n", b"g1 x5 e-0.25\n", b"G1 X\xff5\n", b"\xef\xbb\xbfG1 X1\n",
    b"G1 X1 X2\n", b"G1 X999999999999999\n", b"G1 X9999999999999999\n", b"G1 X0.000000000000001\n",
]


@pytest.mark.parametrize("block", EDGES, ids=range(len(EDGES)))
def test_edge_cases(block: bytes) -> None:
    same(block)


@pytest.fixture(scope="module")
def sliced() -> bytes:
    """The sample part sliced by the built-in slicer (its G-code as a user's plan would read it)."""
    model = Path(fabric.__file__).parent / "data" / "sample_part.stl"
    gcode = slice_model(model.read_bytes(), model.name, load_profile("robot-1.2mm")).gcode
    return gcode.encode() if isinstance(gcode, str) else bytes(gcode)


def test_a_sliced_file(sliced: bytes) -> None:
    same(sliced)
    same(sliced.replace(b"\n", b"\r\n"))                       # Windows line ends
    for a in range(0, len(sliced), len(sliced) // 7):             # blocks cut anywhere, mid-line too
        same(sliced[a:a + 5000])


GCODE_BYTES = st.lists(st.sampled_from(list(b"GXYZEeFNMTS0123456789999.-+ \t;*()\r\n\n\xff\x00")), max_size=200)


@settings(max_examples=1500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(GCODE_BYTES)
def test_fuzzed_gcode_like_text(chars: list[int]) -> None:
    same(bytes(chars))


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_fuzzed_bytes(data: bytes) -> None:
    same(data)


def test_the_planner_reads_a_file_the_same_without_the_helper(sliced: bytes, tmp_path: Path) -> None:
    """A process with the C helpers off (FABRIC_NATIVE=0) interprets a sliced file into the same toolpath."""
    gcode = tmp_path / "sample.gcode"
    gcode.write_bytes(sliced)
    code = ("import hashlib, numpy as np\n"
            "from fabric.gcode.reader import parse_gcode\n"
            f"tp = parse_gcode(open({str(gcode)!r}, 'rb').read())\n"
            "h = hashlib.sha256()\n"
            "for name in ('xyz_mm', 'e_mm', 'feed_mm_s', 'line', 'layer', 'event_row', 'event_kind'):\n"
            "    h.update(np.ascontiguousarray(getattr(tp, name)).tobytes())\n"
            "print(len(tp.xyz_mm), tp.n_lines, h.hexdigest())\n")
    env = {**os.environ, "XDG_CACHE_HOME": os.environ.get("XDG_CACHE_HOME", str(Path.home() / ".cache"))}
    on = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    off = subprocess.run([sys.executable, "-c", code], env={**env, "FABRIC_NATIVE": "0"}, capture_output=True,
                         text=True, check=True).stdout
    assert on == off and int(on.split()[0]) > 100
