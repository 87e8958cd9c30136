"""A printer's G-code macros as buttons, read from Klipper's ``configfile.config``.

Pure: the caller queries ``configfile`` once (it is large, never subscribed) and passes the
``config`` part here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

_PREFIX: Final = "gcode_macro "


@dataclass(frozen=True, slots=True)
class Macro:
    """One ``[gcode_macro NAME]`` a user may press: its name as written and its description."""

    name: str
    description: str


def macros_of(config: Mapping[str, Any]) -> list[Macro]:
    """The printer's macros, sorted by name, without the helpers whose names start with
    ``_`` (Mainsail and Fluidd hide them too: they are called by other macros)."""
    found: dict[str, Macro] = {}
    for section, options in config.items():
        if not isinstance(section, str) or not section.lower().startswith(_PREFIX):
            continue
        name = section[len(_PREFIX) :].strip()
        if not name or name.startswith("_") or not name.replace("_", "").isalnum():
            continue
        description = ""
        if isinstance(options, Mapping) and isinstance(options.get("description"), str):
            description = options["description"].strip()
        # Klipper's commands are case-insensitive: one button per macro.
        found.setdefault(name.upper(), Macro(name.upper(), description))
    return sorted(found.values(), key=lambda m: m.name)
