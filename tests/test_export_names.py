"""Export names valid in every controller language: derived from the file name, sanitised, never refused late."""
from __future__ import annotations

import io
import keyword
import re

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fabric.planning import plan_gcode
from fabric.planning.post import export_program, write_export
from fabric.planning.post.names import DEFAULT_NAME, MAX_NAME_CHARS, program_name
from fabric.robot.cell import Cell

GCODE = "M83\nG1 X20 Y20 Z0.3 F3000\nG1 X40 Y20 E1\nG1 X40 Y40 E1\n"
KRL_IDENT = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,23}")


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


@pytest.mark.parametrize("text, name", [("my-part", "my_part"), ("my part (2)", "my_part_2"),
                                        ("3dbenchy", "p_3dbenchy"), ("end", "end_prog"), ("DEF", "DEF_prog"),
                                        ("Pièce-été", "Piece_ete"),
                                        ("---", DEFAULT_NAME), ("", DEFAULT_NAME), ("a" * 40, "a" * 24),
                                        ("am_print", "am_print")])
def test_names_are_made_valid(text: str, name: str) -> None:
    assert program_name(text) == name


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=60))
def test_any_text_gives_a_name_every_language_takes(text: str) -> None:
    name = program_name(text)
    assert KRL_IDENT.fullmatch(name) and name.isidentifier() and not keyword.iskeyword(name)
    assert len(name) <= MAX_NAME_CHARS and program_name(name) == name


def test_a_hyphenated_file_exports_to_every_language(cell: Cell, tmp_path) -> None:
    plan = plan_gcode(GCODE, cell, filename="my-part v2.gcode").require_runnable()
    assert plan.program.meta["name"] == "my_part_v2" and plan.program.meta["filename"] == "my-part v2.gcode"
    for fmt in ("krl", "urscript", "rapid", "csv"):
        out = io.StringIO()
        write_export(plan.program, fmt, out, cell, name="my-part v2")
        assert out.getvalue()
    out = io.StringIO()
    write_export(plan.program, "krl", out, cell, name="my-part")
    assert "DEF my_part( )" in out.getvalue()
    files = export_program(plan.program, "krl", tmp_path / "krl", name="my-part")
    assert sorted(p.name for p in files) == ["my_part.dat", "my_part.src"]
