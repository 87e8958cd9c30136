"""One reading of numbers from outside, for views, validation and G-code."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from kybercore.core.numbers import finite_number


@pytest.mark.parametrize(
    ("value", "expected"),
    [
        (1.5, 1.5), (3, 3.0), ("0.4", 0.4), (" 7 ", 7.0),
        (True, None), (None, None), ("abc", None), ("", None), ([1], None), ({"a": 1}, None),
        (math.nan, None), (math.inf, None), ("nan", None), ("-inf", None), ("1e999", None),
        (10**400, None),
    ],
)  # fmt: skip
def test_finite_number(value: object, expected: float | None) -> None:
    assert finite_number(value) == expected


@given(st.one_of(st.floats(), st.integers(), st.text(), st.booleans(), st.none()))
def test_finite_number_is_finite_or_none(value: object) -> None:
    number = finite_number(value)
    assert number is None or (type(number) is float and math.isfinite(number))
