"""Reading a printer's active Spoolman spool through its Moonraker (never writing: Moonraker
reports the filament used to Spoolman itself). When: on every (re)subscription, when
Moonraker says another spool was set active, and when a print ends (its weight changed)."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any, Final

from kybercore.core.spools import Spool, SpoolmanState, spool_of
from kybercore.core.view import LivePrinter
from kybercore.errors import MoonrakerRpcError, PrinterError
from kybercore.moonraker.client import MoonrakerClient

log = logging.getLogger(__name__)

SPOOL_SET: Final = "notify_active_spool_set"
_ENDED: Final = frozenset({"complete", "cancelled", "error"})


def print_ended(delta: Mapping[str, Any]) -> bool:
    """Whether a status delta says a print just ended (the spool's weight changed)."""
    stats = delta.get("print_stats")
    return isinstance(stats, Mapping) and stats.get("state") in _ENDED


async def read_spool(client: MoonrakerClient) -> tuple[SpoolmanState, Spool | None]:
    """What Moonraker says of Spoolman, and the active spool if there is one. Nothing is
    guessed: a spool Spoolman does not answer with is no spool (``unreachable``)."""
    try:
        spool_id = await client.active_spool_id()
    except MoonrakerRpcError as exc:
        # 404: no [spoolman] in moonraker.conf; anything else says nothing either way.
        log.debug("%s: no spool id (%s)", client.name, exc.message)
        return ("absent" if exc.rpc_code == 404 else "unknown"), None
    except PrinterError as exc:
        log.debug("%s: no spool id (%s)", client.name, exc.message)
        return "unknown", None
    if spool_id is None:
        return "none", None
    try:
        spool = spool_of(await client.spoolman_spool(spool_id))
    except PrinterError as exc:
        log.debug("%s: spool %d not read (%s)", client.name, spool_id, exc.message)
        return "unreachable", None
    return ("active", spool) if spool is not None else ("unreachable", None)


async def load_spool(client: MoonrakerClient, live: LivePrinter) -> bool:
    """Read the spool into ``live``; whether what the view shows changed."""
    state, spool = await read_spool(client)
    if spool == live.spool and state == live.spoolman:
        return False
    live.spoolman, live.spool = state, spool
    return True
