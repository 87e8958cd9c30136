"""Reading G-code scripts the way Klipper does, for the rules in ``validation``.

Pure functions over strings: they say what a script would do (which commands, which heater
targets, which moves leave the machine's range) and leave the verdicts to ``validation``.

The parsing mirrors Klipper's ``gcode.py``: one command per line, everything after ``;`` is a
comment, a leading ``N<number>`` is skipped, case does not matter; classic commands carry
letter+value parameters (``G1 X10``), extended ones ``KEY=value`` (``SET_HEATER_TEMPERATURE
HEATER=extruder TARGET=200``).
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Literal

from kybercore.core.numbers import finite_number

Heater = Literal["extruder", "bed"]

# Klipper's own split: a run of letters/underscores, or one letter (or * /), then its value.
_ARGS_RE: Final = re.compile(r"([A-Z_]+|[A-Z*/])")
_CLASSIC_RE: Final = re.compile(r"^[A-Z]\d+(\.\d+)?$")
_AXES: Final = "XYZ"
_EPS: Final = 1e-6


@dataclass(frozen=True)
class GcodeCommand:
    """One command of a script: its 1-based line, upper-case name, parameters and text."""

    line: int
    name: str
    params: dict[str, str]
    text: str


@dataclass(frozen=True)
class TemperatureRequest:
    """A command that sets a heater target."""

    line: int
    heater: Heater
    target: float
    text: str


@dataclass(frozen=True)
class MoveOutside:
    """A move that certainly ends outside the machine's range on ``axis``."""

    line: int
    axis: str
    text: str


def parse_gcode(script: str) -> list[GcodeCommand]:
    """Split ``script`` into commands, dropping comments and blank lines."""
    commands: list[GcodeCommand] = []
    for number, raw in enumerate(script.split("\n"), start=1):
        text = raw.strip()
        code = text.split(";", 1)[0].strip()
        if not code:
            continue
        parts = _ARGS_RE.split(code.upper())
        if len(parts) >= 5 and parts[1] == "N":
            parts = parts[:1] + parts[3:]  # drop the line number, as Klipper does
        if len(parts) < 3:
            continue
        name = parts[1] + parts[2].strip()
        if _CLASSIC_RE.match(name):
            params = {parts[i]: parts[i + 1].strip() for i in range(3, len(parts) - 1, 2)}
        else:
            params = _extended_params(code)
        commands.append(GcodeCommand(number, name, params, text))
    return commands


def _extended_params(code: str) -> dict[str, str]:
    """``KEY=value`` parameters of an extended command such as SET_HEATER_TEMPERATURE."""
    rest = code.split(None, 1)[1:]
    args = re.split(r"[#*]", rest[0], maxsplit=1)[0] if rest else ""
    try:
        words = shlex.split(args)
    except ValueError:  # an unbalanced quote: Klipper refuses it too, so nothing to read
        return {}
    return {k.upper(): v for k, _, v in (w.partition("=") for w in words) if k}


def command_names(script: str) -> list[str]:
    """The upper-case command names of ``script``, in order."""
    return [command.name for command in parse_gcode(script)]


def gcode_temperatures(script: str) -> list[TemperatureRequest]:
    """Every heater target the script sets: M104/M109 and M140/M190 ``S``, and
    SET_HEATER_TEMPERATURE for ``extruder*`` and ``heater_bed``. Unparsable values are
    skipped: Klipper rejects them itself."""
    found: list[TemperatureRequest] = []
    for command in parse_gcode(script):
        heater: Heater | None = None
        value: str | None = None
        if command.name in ("M104", "M109"):
            heater, value = "extruder", command.params.get("S")
        elif command.name in ("M140", "M190"):
            heater, value = "bed", command.params.get("S")
        elif command.name == "SET_HEATER_TEMPERATURE":
            target_heater = command.params.get("HEATER", "").lower()
            if target_heater.startswith("extruder"):
                heater = "extruder"
            elif target_heater == "heater_bed":
                heater = "bed"
            value = command.params.get("TARGET")
        target = finite_number(value)
        if heater is not None and target is not None:
            found.append(TemperatureRequest(command.line, heater, target, command.text))
    return found


def first_move_outside(
    script: str, minimum: Sequence[float], maximum: Sequence[float]
) -> MoveOutside | None:
    """The first G0-G3 move that certainly ends outside ``minimum``..``maximum`` (X, Y, Z).

    Conservative on purpose, so a warning is never a false alarm for a normal script:

    * the toolhead starts somewhere inside the range (Klipper refuses moves before homing);
    * each axis is tracked as an interval of possible positions;
    * until the script says G90 or G91 the mode is unknown, and a target counts as outside
      only if it is outside both when read absolute and when read relative;
    * G28 puts the homed axes back to "somewhere inside";
    * after G92, SET_GCODE_OFFSET or SET_KINEMATIC_POSITION the script's coordinates no
      longer match the machine's, so those axes are no longer checked.

    Klipper stops a script at the first move it refuses, so only the first one matters.
    """
    low = [float(v) for v in minimum]
    high = [float(v) for v in maximum]
    where = [(low[i], high[i]) for i in range(3)]
    tracked = [True, True, True]
    mode: Literal["absolute", "relative"] | None = None
    for command in parse_gcode(script):
        name = command.name
        if name == "G90":
            mode = "absolute"
        elif name == "G91":
            mode = "relative"
        elif name == "G28":
            homed = [i for i, axis in enumerate(_AXES) if axis in command.params] or [0, 1, 2]
            for i in homed:
                where[i] = (low[i], high[i])
        elif name in ("G92", "SET_GCODE_OFFSET", "SET_KINEMATIC_POSITION"):
            named = [i for i, a in enumerate(_AXES) if any(k.startswith(a) for k in command.params)]
            # Without axes, G92 and SET_KINEMATIC_POSITION redefine all of them.
            if not named and name != "SET_GCODE_OFFSET":
                named = [0, 1, 2]
            for i in named:
                tracked[i] = False
        elif name in ("G0", "G1", "G2", "G3"):
            for i, axis in enumerate(_AXES):
                value = finite_number(command.params.get(axis))
                if value is None:
                    continue
                lo, hi = where[i]
                if mode == "absolute":
                    target = (value, value)
                elif mode == "relative":
                    target = (lo + value, hi + value)
                else:
                    target = (min(value, lo + value), max(value, hi + value))
                if tracked[i] and (target[0] > high[i] + _EPS or target[1] < low[i] - _EPS):
                    return MoveOutside(command.line, axis, command.text)
                # Clamp: a move that went through lands inside the range.
                where[i] = (max(target[0], low[i]), min(target[1], high[i]))
                if where[i][0] > where[i][1]:
                    where[i] = (low[i], high[i])
    return None
