"""Fixed-point text: exactly the characters of ``"%.<d>f"``, ties and edge values included, on both paths (the C
helper ``fabric/native/numtext.c`` and numpy's)."""
from __future__ import annotations

import shutil

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fabric.planning.post import numtext
from fabric.planning.post.numtext import ChoiceColumn, FixedColumn, format_rows, trimmed_text


@pytest.fixture(params=["native", "numpy"], autouse=True)
def path(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Every test on both paths: the C helper's, and numpy's (the helper switched off)."""
    if request.param == "numpy":
        monkeypatch.setattr(numtext, "use_native", False)
    elif numtext._numtext() is None:
        pytest.fail("the C helper did not load" if shutil.which("cc") else "no C compiler here")
    return str(request.param)

_EDGES = [0.0, -0.0, -1e-9, 1e-9, 0.5, 1.5, 2.5, -2.5, 0.125, -0.125, 0.0005, 1.00005, 1e20, -1e20, np.nan, np.inf,
          -np.inf, 123456789.123456, 9.99995, 99999.99995]


_FINITE = [v for v in _EDGES if np.isfinite(v)]


@pytest.mark.parametrize("decimals", [0, 1, 3, 4, 5, 7, 12])
def test_same_text_as_printf(decimals: int) -> None:
    rng = np.random.default_rng(decimals)
    values = np.concatenate([rng.normal(0, 300, 20_000), rng.uniform(-1, 1, 20_000),
                             np.round(rng.normal(0, 1, 20_000), decimals) + 0.5 * 10.0 ** -decimals, _FINITE])
    got = format_rows([FixedColumn(values, decimals)]).decode()
    assert got == "".join(f"%.{decimals}f\n" % v for v in values.tolist())


def test_values_not_finite_in_a_block_are_written_as_python_writes_them() -> None:
    """The C helper leaves a block with NaN or infinity to numpy: the block is still written whole."""
    values = np.array(_EDGES * 3)
    got = format_rows([FixedColumn(np.arange(len(values)), 0), FixedColumn(values, 4)]).decode()
    assert got == "".join(f"{i},{v:.4f}\n" for i, v in enumerate(values.tolist()))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=1, max_size=40),
       st.integers(0, 12), st.lists(st.integers(-2**63, 2**63 - 1), min_size=1, max_size=40))
def test_fuzz_rows_are_printf(path: str, floats: list[float], decimals: int, ints: list[int]) -> None:
    n = min(len(floats), len(ints))
    f, i = np.array(floats[:n]), np.array(ints[:n], dtype=np.int64)
    got = format_rows([FixedColumn(i, 0), FixedColumn(f, decimals), b"x"]).decode()
    assert got == "".join(f"{a},%.{decimals}f,x\n" % b for a, b in zip(i.tolist(), f.tolist(), strict=True))


def test_integer_and_constant_columns_and_separator() -> None:
    ints = np.array([-1, 0, 7, 10, 99, 100, 10**12])
    text = format_rows([FixedColumn(ints, 0), b"", FixedColumn(ints.astype(float) / 8, 3)], sep=b";").decode()
    assert text == "".join(f"{i};;{i / 8:.3f}\n" for i in ints.tolist())


def test_bad_decimals_refused() -> None:
    with pytest.raises(ValueError):
        FixedColumn(np.zeros(3), 13)


@pytest.mark.parametrize("decimals", [1, 2, 3, 6])
def test_trimmed_same_text_as_rapid_numbers(decimals: int) -> None:
    rng = np.random.default_rng(10 + decimals)
    values = np.concatenate([rng.normal(0, 300, 20_000), np.round(rng.normal(0, 50, 20_000), 1),
                             np.round(rng.uniform(-1, 1, 20_000), decimals) + 0.5 * 10.0 ** -decimals,
                             -np.abs(rng.uniform(0, 0.4, 100)) * 10.0 ** -decimals, _EDGES])
    got = format_rows([FixedColumn(values, decimals, trim=True)]).decode()
    assert got == "".join(trimmed_text(v, decimals) + "\n" for v in values.tolist())
    assert trimmed_text(-0.0001, 3) == "0" and trimmed_text(100.0, 3) == "100" and trimmed_text(0.25, 3) == "0.25"


def test_choice_column_writes_the_chosen_text() -> None:
    text = format_rows([ChoiceColumn(np.array([1, 0, 2, 1]), [b"a", b"bcd", b""]), FixedColumn(np.arange(4), 0)],
                       sep=b"|").decode()
    assert text == "bcd|0\na|1\n|2\nbcd|3\n"


def test_unsigned_and_fixed_point_integer_columns() -> None:
    """Integers past int64 and integers read as fixed-point (the C helper leaves both to numpy): the same text."""
    columns = [FixedColumn(np.array([2**64 - 1, 7], dtype=np.uint64), 0), FixedColumn(np.array([12345, -7]), 3),
               FixedColumn(np.array([3, 250], dtype=np.uint8), 0)]
    text = format_rows(columns).decode()
    assert text == "18446744073709551615,12.345,3\n7,-0.007,250\n"


def test_columns_of_rows_are_read_where_they_lie() -> None:
    """A column of rows (``xyz[:, 1]``), a reversed view, a broadcast value and big-endian values: the text
    of the same numbers copied out (the C helper reads a whole-element stride in place, copies the rest)."""
    rng = np.random.default_rng(2)
    xyz = rng.normal(0, 200, (5000, 3))
    ints = rng.integers(-10**9, 10**9, (5000, 2))
    cols = [FixedColumn(xyz[:, 1], 4), FixedColumn(ints[:, 1], 0), FixedColumn(xyz[::-1, 2], 3),
            FixedColumn(np.broadcast_to(np.float64(2.5), 5000), 2), FixedColumn(xyz[:, 0].astype(">f8"), 5)]
    copied = [FixedColumn(np.array(c.values, dtype=c.values.dtype.newbyteorder("=")), c.decimals) for c in cols]
    assert format_rows(cols) == format_rows(copied)
    assert format_rows(cols).decode().splitlines()[0] == (
        f"{xyz[0, 1]:.4f},{ints[0, 1]},{xyz[-1, 2]:.3f},2.50,{xyz[0, 0]:.5f}")
