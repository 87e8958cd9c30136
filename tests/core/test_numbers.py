"""One reading of numbers from outside, for views, validation and G-code."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from kybercore.core.numbers import finite_number, rounded


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


@given(
    st.floats(min_value=-1e9, max_value=1e9, allow_nan=False, allow_infinity=False),
    st.integers(min_value=0, max_value=4),
)
def test_rounded_is_round_but_on_a_written_half(value: float, digits: int) -> None:
    # Where they differ, the value sits on a half as written (0.15: one more decimal than
    # kept), and both are one unit apart.
    ours, theirs = rounded(value, digits), round(value, digits)
    if ours != theirs:
        assert math.isclose(abs(ours - theirs), 10.0**-digits, rel_tol=1e-6)
        assert math.isclose(value * 10**digits % 1, 0.5, abs_tol=1e-6)


@pytest.mark.parametrize(
    ("value", "digits", "expected"),
    [(0.15, 1, 0.2), (2.675, 2, 2.68), (209.96, 1, 210.0), (-0.04, 1, 0.0), (1e300, 2, 1e300)],
)
def test_rounded_as_a_reader_expects(value: float, digits: int, expected: float) -> None:
    assert rounded(value, digits) == expected


def test_rounded_leaves_what_is_not_a_number_to_round() -> None:
    assert math.isnan(rounded(math.nan, 1))
    assert rounded(math.inf, 2) == math.inf
