"""Each cell's native export (RAPID for ABB, KRL for KUKA, URScript for UR, CSV for the Panda), from a planned
square, parsed back against the program; the 6-axis languages refuse a 7-axis program."""
from __future__ import annotations

import csv
import io
import re

import numpy as np
import pytest

from fabric.motion.program import MOVEJ, MOVEL
from fabric.motion.testprog import square_program
from fabric.planning.post import write_export
from fabric.planning.post.csv import csv_columns
from fabric.robot.cell import CELLS_DIR, NATIVE_EXPORTS, Cell
from fabric.wire.errors import ConfigError, ValidationError

NATIVE = {"irb140": "rapid", "kr6r700": "krl", "ur5": "urscript", "ur10": "urscript", "panda": "csv"}


@pytest.fixture(scope="module", params=sorted(NATIVE))
def cell(request) -> Cell:
    return Cell.builtin(request.param)


def _export(cell: Cell, fmt: str) -> tuple[object, str]:
    prog = square_program(cell)
    out = io.StringIO()
    write_export(prog, fmt, out, cell, name="square")
    return prog, out.getvalue()


def test_the_cell_names_its_native_export(cell: Cell) -> None:
    assert cell.native_export == NATIVE[cell.name] == NATIVE_EXPORTS[cell.brand]
    assert cell.to_dict()["native_export"] == cell.native_export


def test_the_native_export_has_every_target_and_the_joint_moves(cell: Cell) -> None:
    prog, text = _export(cell, cell.native_export)
    n_lin, n_joint = int((prog.op == MOVEL).sum()), int((prog.op == MOVEJ).sum())
    q_deg = np.degrees(prog.q_rad[prog.op == MOVEJ])
    if cell.native_export == "krl":
        # KRL: LIN per linear target (or $VEL.CP / $APO.CDIS set before it), PTP with A1..A6 per joint move
        assert len(re.findall(r"^\s*LIN ", text, re.M)) == n_lin
        ptp = re.findall(r"PTP \{(.*)\}", text)
        assert len(ptp) == n_joint
        got = np.array([[float(v.split()[1]) for v in p.split(",")] for p in ptp])
        np.testing.assert_allclose(got, q_deg, atol=1e-4)
        assert "$VEL.CP=" in text and "$APO.CDIS=" in text and "$VEL_AXIS[1]=" in text
    elif cell.native_export == "urscript":
        assert len(re.findall(r"movel\(", text)) == n_lin
        mj = re.findall(r"movej\(\[(.*?)\]", text)
        got = np.degrees([[float(v) for v in m.split(",")] for m in mj])
        np.testing.assert_allclose(got, q_deg, atol=1e-4)
    elif cell.native_export == "rapid":
        assert len(re.findall(r"\b(?:MoveL|TriggL) ", text)) == n_lin
        assert len(re.findall(r"MoveAbsJ ", text)) == n_joint
    else:
        rows = list(csv.reader(io.StringIO(text)))
        assert rows[0] == csv_columns(cell.robot.nq)
        assert [f"q{j}_deg" for j in range(1, 8)] == rows[0][8:15]         # the Panda: seven joint columns
        got = np.array([[float(v) for v in r[8:8 + cell.robot.nq]] for r in rows[1:]])
        np.testing.assert_allclose(got, np.degrees(prog.q_rad[prog.op <= MOVEL]), atol=1e-5)


def test_six_axis_languages_refuse_a_seven_axis_program() -> None:
    panda = Cell.builtin("panda")
    prog = square_program(panda)
    assert prog.nq == 7
    for fmt in ("rapid", "krl", "urscript"):
        with pytest.raises(ValidationError, match="6-axis arm") as exc:
            write_export(prog, fmt, io.StringIO(), panda)
        assert exc.value.details["nq"] == 7


def test_an_unknown_brand_is_a_config_error() -> None:
    text = (CELLS_DIR / "ur5.toml").read_text()
    with pytest.raises(ConfigError, match=r"robot\.brand"):
        Cell.from_toml_text(text.replace('brand = "ur"', 'brand = "acme"'))
