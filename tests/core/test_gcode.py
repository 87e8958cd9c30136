"""Reading G-code scripts as Klipper does: commands, heater targets, moves out of range."""

from __future__ import annotations

import pytest

from kybercore.core.gcode import (
    TemperatureRequest,
    command_names,
    first_move_outside,
    gcode_temperatures,
    parse_gcode,
)

LOW = (0.0, 0.0, 0.0)
HIGH = (220.0, 220.0, 250.0)


def test_parse_drops_comments_blank_lines_and_line_numbers() -> None:
    script = "; just a comment\n\n  g1 x10 Y20.5 ; move\nN42 M104 S200*77\nM117 Hello there"
    commands = parse_gcode(script)
    assert [c.name for c in commands] == ["G1", "M104", "M117"]
    assert commands[0].line == 3
    assert commands[0].params == {"X": "10", "Y": "20.5"}
    assert commands[0].text == "g1 x10 Y20.5 ; move"
    assert commands[1].params["S"] == "200"


def test_parse_extended_commands_keep_key_value_params() -> None:
    [command] = parse_gcode("SET_HEATER_TEMPERATURE HEATER=extruder TARGET=205 # note")
    assert command.name == "SET_HEATER_TEMPERATURE"
    assert command.params == {"HEATER": "extruder", "TARGET": "205"}


def test_parse_keeps_digits_in_macro_names_and_survives_bad_quotes() -> None:
    assert command_names('LOAD_FILAMENT2 SPEED=5\nRESPOND MSG="unbalanced') == [
        "LOAD_FILAMENT2",
        "RESPOND",
    ]


def test_command_names_ignore_commands_inside_comments() -> None:
    assert command_names("G28 ; then M112 if it goes wrong\n;M112") == ["G28"]


def test_temperatures_from_m_codes_and_set_heater_temperature() -> None:
    script = (
        "M104 S210\nM109 T0 S215\nm140 s60\nM190 S65\n"
        "SET_HEATER_TEMPERATURE HEATER=extruder1 TARGET=230\n"
        "SET_HEATER_TEMPERATURE HEATER=heater_bed TARGET=70\n"
        "SET_HEATER_TEMPERATURE HEATER=chamber TARGET=40\n"
        "M104 Sabc\nM104\n"
    )
    found = gcode_temperatures(script)
    assert [(t.heater, t.target) for t in found] == [
        ("extruder", 210.0),
        ("extruder", 215.0),
        ("bed", 60.0),
        ("bed", 65.0),
        ("extruder", 230.0),
        ("bed", 70.0),
    ]
    assert found[0] == TemperatureRequest(1, "extruder", 210.0, "M104 S210")


@pytest.mark.parametrize(
    ("script", "axis"),
    [
        ("G90\nG1 X230 F3000", "X"),
        ("G90\nG0 Y-1", "Y"),
        ("G90\nG1 Z260", "Z"),
        ("G90\nG1 X10\nG91\nG1 X215", "X"),  # 10 + 215 > 220
        ("G1 X500", "X"),  # mode unknown: out both as absolute and as relative
        ("G1 X-300", "X"),
        ("G28\nG91\nG1 Z-300", "Z"),
    ],
)
def test_moves_that_certainly_leave_the_volume(script: str, axis: str) -> None:
    move = first_move_outside(script, LOW, HIGH)
    assert move is not None
    assert move.axis == axis
    assert move.line == len(script.split("\n"))


@pytest.mark.parametrize(
    "script",
    [
        "G90\nG1 X220 Y0 Z250",  # exactly on the limits
        "G1 X150",  # unknown mode: 150 absolute is fine
        "G91\nG1 X100",  # relative from an unknown place inside: may be fine
        "G90\nG1 X100\nG91\nG1 X100",  # 200
        "G92 X0\nG90\nG1 X300",  # after G92 the script's coordinates are not the machine's
        "G92\nG1 Z400",
        "SET_GCODE_OFFSET Z=1\nG90\nG1 Z260",
        "G90\nG1 X10\nG28 X\nG91\nG1 X215",  # G28 forgets where X was: could be at 0
        "G1 E500 F100",  # extrusion only
        "G90\nG1 Xabc",  # unparsable: Klipper will refuse it, not our business
    ],
)
def test_moves_that_may_be_fine_do_not_warn(script: str) -> None:
    assert first_move_outside(script, LOW, HIGH) is None


def test_only_the_first_move_outside_is_reported() -> None:
    move = first_move_outside("G90\nG1 X10\nG1 Y300\nG1 X300", LOW, HIGH)
    assert move is not None
    assert (move.line, move.axis, move.text) == (3, "Y", "G1 Y300")
