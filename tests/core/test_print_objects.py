"""Klipper's exclude_object status read defensively: what is not a name or a point is left
out, never an error."""

from __future__ import annotations

import math

from kybercore.core.print_objects import PrintObject, PrintObjects, print_objects_of


def test_a_klipper_without_exclude_object_has_nothing_to_exclude() -> None:
    assert print_objects_of(None) == PrintObjects(available=False)
    assert print_objects_of({}) == PrintObjects(available=True)


def test_objects_excluded_and_current_are_read_as_klipper_reports_them() -> None:
    status = {
        "objects": [
            {"name": "CUBE_1", "center": [55, 55.5], "polygon": [[50, 50], [60, 50], [60, 60]]},
            {"name": "CUBE_2"},
        ],
        "excluded_objects": ["CUBE_2"],
        "current_object": "CUBE_1",
    }
    found = print_objects_of(status)
    assert found.objects == (
        PrintObject("CUBE_1", (55.0, 55.5), ((50.0, 50.0), (60.0, 50.0), (60.0, 60.0))),
        PrintObject("CUBE_2", None, ()),
    )
    assert (found.excluded, found.current) == (("CUBE_2",), "CUBE_1")


def test_what_a_peer_may_send_instead_is_left_out() -> None:
    status = {
        "objects": [
            {"name": "", "center": [1, 2]},
            {"name": "TWO WORDS"},  # would not be one EXCLUDE_OBJECT NAME= parameter
            {"name": "A;B"},  # would exclude A
            {"name": 7},
            "CUBE",
            {"name": "OK", "center": [True, 2], "polygon": [[1, math.nan], [1], "x", [3, 4]]},
        ],
        "excluded_objects": "CUBE",
        "current_object": None,
    }
    found = print_objects_of(status)
    assert found.objects == (PrintObject("OK", None, ((3.0, 4.0),)),)
    assert (found.excluded, found.current) == ((), None)
