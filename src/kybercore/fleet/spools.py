"""Reading a printer's active Spoolman spool through its Moonraker (never writing: Moonraker
reports the filament used to Spoolman itself). When: on every (re)subscription, when
Moonraker says another spool was set active, and when a print ends (its weight changed)."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any, Final

from kybercore.core.spools import Spool, spool_of
from kybercore.core.view import LivePrinter
from kybercore.errors import PrinterError
from kybercore.moonraker.client import MoonrakerClient

log = logging.getLogger(__name__)

SPOOL_SET: Final = "notify_active_spool_set"
_ENDED: Final = frozenset({"complete", "cancelled", "error"})


def print_ended(delta: Mapping[str, Any]) -> bool:
    """Whether a status delta says a print just ended (the spool's weight changed)."""
    stats = delta.get("print_stats")
    return isinstance(stats, Mapping) and stats.get("state") in _ENDED


async def read_spool(client: MoonrakerClient) -> Spool | None:
    """The active spool, or None: no ``[spoolman]`` in moonraker.conf, no spool set, or
    Spoolman unreachable (then nothing is known, and nothing is guessed)."""
    try:
        spool_id = await client.active_spool_id()
        return None if spool_id is None else spool_of(await client.spoolman_spool(spool_id))
    except PrinterError as exc:
        log.debug("%s: no spool (%s)", client.name, exc.message)
        return None


async def load_spool(client: MoonrakerClient, live: LivePrinter) -> bool:
    """Read the spool into ``live``; whether it changed."""
    spool = await read_spool(client)
    if spool == live.spool:
        return False
    live.spool = spool
    return True
