"""A printer's active Spoolman spool, as Moonraker's ``[spoolman]`` reports it. Pure.

Moonraker knows which spool is loaded (``/server/spoolman/spool_id``) and relays Spoolman's
API (``/server/spoolman/proxy``); it also reports the filament used to Spoolman, so
KyberCore only reads: material and remaining weight feed validation and the queue.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Final, Literal

from kybercore.core.numbers import finite_number

_HEX: Final = re.compile(r"^[0-9a-fA-F]{6}$")

LOW_FILAMENT_G: Final = 100.0
"""Below this many grams a spool is shown as running low: about an evening's print, so an
operator has time to fetch the next spool before a job is refused for want of filament."""

SpoolmanState = Literal["unknown", "absent", "none", "active", "unreachable"]
"""What a printer's Moonraker says about Spoolman: not read yet; no ``[spoolman]`` in its
moonraker.conf; no spool set active; a spool active and read; a spool set but Spoolman did
not answer with it."""


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
            "low": self.low,
        }

    @property
    def low(self) -> bool:
        """Fewer than :data:`LOW_FILAMENT_G` grams left (unknown weight is not low)."""
        return self.remaining_g is not None and self.remaining_g < LOW_FILAMENT_G


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


def spool_map(views: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """Which spool is on which printer, from the printers' views (``GET /api/spools``).

    ``spools``: each active spool once, with every printer holding it (more than one means
    the same spool was set active on two printers: a mistake worth showing, not hiding),
    fewest grams first, so the spools to replace soon lead. ``without``: the printers with
    no spool to show, and why (their ``spoolman`` state).
    """
    spools: dict[int, dict[str, Any]] = {}
    without: list[dict[str, Any]] = []
    for view in views:
        holder = {"id": view.get("id"), "name": view.get("name")}
        shown = view.get("spool")
        if not isinstance(shown, Mapping) or not isinstance(shown.get("id"), int):
            without.append({**holder, "spoolman": view.get("spoolman", "unknown")})
            continue
        entry = spools.setdefault(shown["id"], {**shown, "printers": []})
        entry["printers"].append(holder)
    ordered = sorted(
        spools.values(),
        key=lambda s: (s["remaining_g"] is None, s["remaining_g"] or 0.0, s["id"]),
    )
    return {"low_below_g": LOW_FILAMENT_G, "spools": ordered, "without": without}
