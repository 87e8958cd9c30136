"""Which printer counts as heating, and which power group it draws from."""

from __future__ import annotations

from typing import Any

import pytest

from kybercore.jobs.heating import HEATING_MARGIN, is_heating, power_group
from kybercore.registry.models import PrinterConfig


def heaters(extruder: tuple[Any, Any] | None = None, bed: tuple[Any, Any] | None = None,
            **more: dict[str, Any]) -> dict[str, Any]:  # fmt: skip
    """A Moonraker status with (temperature, target) per heater."""
    status: dict[str, Any] = {"print_stats": {"state": "printing"}, "fan": {"speed": 1.0}}
    for name, pair in (("extruder", extruder), ("heater_bed", bed)):
        if pair is not None:
            status[name] = {"temperature": pair[0], "target": pair[1], "power": 1.0}
    return {**status, **more}


@pytest.mark.parametrize(
    ("status", "heating"),
    [
        (heaters(), False),  # no heater reported at all
        (heaters((21.0, 0.0), (21.0, 0.0)), False),  # targets off
        (heaters((21.0, 210.0), (60.0, 60.0)), True),  # the hotend heats
        (heaters((210.0, 210.0), (25.0, 60.0)), True),  # the bed heats
        (heaters((210.0, 210.0), (60.2, 60.0)), False),  # both there (overshoot too)
        (heaters((206.0, 210.0)), False),  # within the margin: holding, not heating
        (heaters((210.0 - HEATING_MARGIN, 210.0)), False),  # exactly at the margin
        (heaters((210.0 - HEATING_MARGIN - 0.1, 210.0)), True),  # just past it
        (heaters((200.0, 20.0)), False),  # cooling down towards a low target
        (heaters((None, 210.0)), True),  # a target and no reading: on the safe side
        (heaters(("hot", 210.0)), True),  # junk for a reading: unknown, safe side
        (heaters((float("nan"), 210.0)), True),
        (heaters((21.0, None)), False),  # no target
        (heaters((21.0, float("nan"))), False),
        (heaters((21.0, True)), False),  # a boolean is not a temperature
        (heaters((21.0, -5.0)), False),
        (heaters((21.0, "210")), True),  # numeric strings read as numbers
        (heaters(extruder1={"temperature": 20.0, "target": 250.0}), True),  # second hotend
        (heaters(**{"heater_generic chamber": {"temperature": 20.0, "target": 50.0}}), True),
        (heaters(temperature_sensor={"temperature": 20.0, "target": 50.0}), False),  # no heater
        (heaters(extruder="off"), False),  # not an object
    ],
)
def test_is_heating(status: dict[str, Any], heating: bool) -> None:
    assert is_heating(status) is heating


def config(**fields: Any) -> PrinterConfig:
    return PrinterConfig(id="p1", name="P1", moonraker_url="http://10.0.0.5:7125", **fields)


def test_the_power_group_is_its_own_field_else_the_location() -> None:
    assert power_group(config(location="Room B", power_group="Breaker 3")) == "Breaker 3"
    assert power_group(config(location=" Room B ")) == "Room B"
    assert power_group(config(location="Room B", power_group="  ")) == "Room B"
    assert power_group(config()) == ""


def test_power_group_is_stored_and_optional() -> None:
    stored = config(power_group="Breaker 3").to_file_dict()
    assert stored["power_group"] == "Breaker 3"
    assert PrinterConfig.model_validate({**stored, "power_group": ""}).power_group == ""
    del stored["power_group"]  # a printers.json written before the field existed
    assert PrinterConfig.model_validate(stored).power_group == ""
    assert config(power_group="B3").public().power_group == "B3"
