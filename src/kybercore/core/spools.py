"""A printer's active Spoolman spool, as Moonraker's ``[spoolman]`` reports it. Pure.

Moonraker knows which spool is loaded (``/server/spoolman/spool_id``) and relays Spoolman's
API (``/server/spoolman/proxy``); it also reports the filament used to Spoolman, so
KyberCore only reads: material and remaining weight feed validation and the queue.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Final

from kybercore.core.numbers import finite_number

_HEX: Final = re.compile(r"^[0-9a-fA-F]{6}$")


@dataclass(frozen=True)
class Spool:
    """The spool on a printer: what it is and how much is left."""

    id: int
    name: str
    material: str
    color_hex: str
    """``RRGGBB``, or "" when Spoolman has none."""
    remaining_g: float | None

    @cached_property
    def public(self) -> dict[str, Any]:
        """As the API and the browser see it; built once, as fuse() runs on every update."""
        return {
            "id": self.id,
            "name": self.name,
            "material": self.material,
            "color_hex": self.color_hex,
            "remaining_g": self.remaining_g,
        }


def spool_of(payload: Any) -> Spool | None:
    """A :class:`Spool` from Spoolman's ``GET /api/v1/spool/{id}``; None if it is not one."""
    if not isinstance(payload, Mapping) or not isinstance(payload.get("id"), int):
        return None
    filament = payload.get("filament")
    filament = filament if isinstance(filament, Mapping) else {}
    vendor = filament.get("vendor")
    vendor_name = vendor.get("name") if isinstance(vendor, Mapping) else None
    name = " ".join(str(v) for v in (vendor_name, filament.get("name")) if isinstance(v, str))
    color = filament.get("color_hex")
    remaining = finite_number(payload.get("remaining_weight"))
    return Spool(
        id=payload["id"],
        name=name.strip(),
        material=str(filament.get("material") or "").strip(),
        color_hex=color if isinstance(color, str) and _HEX.match(color) else "",
        remaining_g=None if remaining is None else round(max(remaining, 0.0), 1),
    )


def filament_needed_g(meta: Mapping[str, Any]) -> float | None:
    """Grams of filament a sliced file needs, if it says: ``filament_weight_total``, else
    the sum of ``filament_weights`` (per extruder; some slicers write only those)."""
    needed = finite_number(meta.get("filament_weight_total"))
    if needed is None and isinstance(meta.get("filament_weights"), list):
        weights = [finite_number(w) for w in meta["filament_weights"]]
        needed = sum(w for w in weights if w is not None) or None
    return needed if needed is not None and needed > 0 else None
