"""Vectorised fixed-point text: exactly the characters of ``"%.<d>f"``, ties and edge values included."""
from __future__ import annotations

import numpy as np
import pytest

from fabric.planning.post.numtext import ChoiceColumn, FixedColumn, format_rows, trimmed_text

_EDGES = [0.0, -0.0, -1e-9, 1e-9, 0.5, 1.5, 2.5, -2.5, 0.125, -0.125, 0.0005, 1.00005, 1e20, -1e20, np.nan, np.inf,
          -np.inf, 123456789.123456, 9.99995, 99999.99995]


@pytest.mark.parametrize("decimals", [0, 1, 3, 4, 5, 7])
def test_same_text_as_printf(decimals: int) -> None:
    rng = np.random.default_rng(decimals)
    values = np.concatenate([rng.normal(0, 300, 20_000), rng.uniform(-1, 1, 20_000),
                             np.round(rng.normal(0, 1, 20_000), decimals) + 0.5 * 10.0 ** -decimals, _EDGES])
    got = format_rows([FixedColumn(values, decimals)]).decode()
    assert got == "".join(f"%.{decimals}f\n" % v for v in values.tolist())


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
