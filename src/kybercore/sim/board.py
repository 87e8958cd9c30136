"""Pin layout of the virtual board, shared by the virtual MCU and the printer.cfg renderer.

The MCU needs to know which heater pin warms which thermistor pin, and printer.cfg must name
the same pins, so both sides read them from here.
"""

from __future__ import annotations

from dataclasses import dataclass

PIN_BANKS = ("PA", "PB", "PC")
PINS_PER_BANK = 16


@dataclass(frozen=True)
class AxisPins:
    """Pins of one stepper driver; `endstop` is empty for the extruder."""

    step: str
    dir: str
    enable: str
    endstop: str = ""


STEPPER_X = AxisPins(step="PA0", dir="PA1", enable="PA2", endstop="PB0")
STEPPER_Y = AxisPins(step="PA3", dir="PA4", enable="PA5", endstop="PB1")
STEPPER_Z = AxisPins(step="PA6", dir="PA7", enable="PA8", endstop="PB2")
STEPPER_E = AxisPins(step="PA9", dir="PA10", enable="PA11")

HOTEND_HEATER = "PB3"
BED_HEATER = "PB4"
PART_FAN = "PB5"
HOTEND_SENSOR = "PC0"
BED_SENSOR = "PC1"


def pin_enumeration() -> dict[str, list[int]]:
    """The data dictionary's `pin` enumeration, as ranges: {"PA0": [0, 16], ...}."""
    return {
        f"{bank}0": [index * PINS_PER_BANK, PINS_PER_BANK] for index, bank in enumerate(PIN_BANKS)
    }


def pin_name(number: int) -> str:
    """Name of the pin with enumeration value `number` (ValueError if out of range)."""
    bank, offset = divmod(number, PINS_PER_BANK)
    if not 0 <= bank < len(PIN_BANKS):
        raise ValueError(f"no pin number {number}")
    return f"{PIN_BANKS[bank]}{offset}"
