"""Numbers from outside: decoded JSON, slicer metadata and G-code parameters."""

from __future__ import annotations

import math


def finite_number(value: object) -> float | None:
    """``value`` as a finite float, or None: booleans, NaN, infinities and junk are not numbers.

    Accepts what Moonraker's JSON, a slicer's header or a G-code parameter can hold: ints,
    floats and numeric strings.
    """
    if type(value) is float:  # nearly always (decoded JSON): the fast path of fuse()
        return value if math.isfinite(value) else None
    if type(value) is int:  # byte offsets, layers: finite unless past float's range
        try:
            return float(value)
        except OverflowError:
            return None
    if isinstance(value, bool) or not isinstance(value, int | str):
        return None
    try:
        number = float(value)
    except (ValueError, OverflowError):  # OverflowError: an int past float's range
        return None
    return number if math.isfinite(number) else None
