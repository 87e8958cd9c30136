"""The printer page's macro buttons, from Klipper's configfile.config."""

from __future__ import annotations

from kybercore.core.macros import Macro, macros_of


def test_macros_are_sorted_upper_case_without_helpers_or_other_sections() -> None:
    config = {
        "printer": {"kinematics": "cartesian"},
        "gcode_macro park": {"description": "Park it", "gcode": "G1 X0"},
        "gcode_macro CANCEL_PRINT": {"rename_existing": "CANCEL_PRINT_BASE", "gcode": "..."},
        "gcode_macro _helper": {"gcode": "M117"},
        "gcode_macro  LOAD_FILAMENT ": {"gcode": "G1 E50"},
        "gcode_macro": {"gcode": "nameless"},
        "gcode_macro bad name": {"gcode": "spaces are not a command"},
        "fan": {"pin": "PA1"},
    }
    assert macros_of(config) == [
        Macro("CANCEL_PRINT", ""),
        Macro("LOAD_FILAMENT", ""),
        Macro("PARK", "Park it"),
    ]


def test_one_button_per_macro_whatever_its_case() -> None:
    config = {"gcode_macro Park": {"description": "first"}, "gcode_macro PARK": {}}
    assert macros_of(config) == [Macro("PARK", "first")]


def test_a_malformed_config_gives_no_buttons_rather_than_an_error() -> None:
    assert macros_of({"gcode_macro X": "not a section", 3: {}}) == [Macro("X", "")]
    assert macros_of({}) == []
