"""Which printers are heating, and which power group shares a breaker with which: pure.

Fifty printers preheating at once trip a breaker (one farm counted 30 kW at start), so the
planner lets at most K printers of a power group heat at the same time. A printer heats
from the moment a target is set until the hotend and the bed are within a few degrees of
it; after that a heater only holds its temperature, which draws a fraction of the power.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Final

from kybercore.core.numbers import finite_number
from kybercore.registry.models import PrinterConfig

HEATING_MARGIN: Final = 5.0
"""°C below its target at which a heater still counts as heating (full power)."""

_HEATER_PREFIXES: Final = ("extruder", "heater_bed", "heater_generic ")
_FIRST_LETTERS: Final = "".join(sorted({prefix[0] for prefix in _HEATER_PREFIXES}))


def is_heating(status: Mapping[str, Any]) -> bool:
    """Whether any heater in a Moonraker status has a target and is more than
    :data:`HEATING_MARGIN` below it.

    A heater with a target but no readable temperature counts as heating: the budget is
    there to keep a breaker on, so an unknown reading is taken on the safe side.
    """
    for name, heater in status.items():
        # Runs for every temperature update (the dispatcher's budget): a one-letter test
        # turns most objects away before the prefix test, and exact dicts skip the ABC.
        if name[:1] not in _FIRST_LETTERS or not name.startswith(_HEATER_PREFIXES):
            continue
        if type(heater) is not dict and not isinstance(heater, Mapping):
            continue
        target = finite_number(heater.get("target"))
        if target is None or target <= 0:
            continue
        temperature = finite_number(heater.get("temperature"))
        if temperature is None or temperature < target - HEATING_MARGIN:
            return True
    return False


def power_group(config: PrinterConfig) -> str:
    """The printer's power group: its ``power_group`` field, else its ``location``.

    Printers with neither share the group ``""``: without knowing their circuits, the
    budget treats them as one.
    """
    return config.power_group.strip() or config.location.strip()
