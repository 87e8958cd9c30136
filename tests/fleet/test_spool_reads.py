"""How a printer's Moonraker answers become a Spoolman state (no [spoolman], no spool set,
Spoolman away) and a spool, with a stub client: what the Spools view says of each printer."""

from __future__ import annotations

from typing import cast

import pytest

from kybercore.core.spools import Spool
from kybercore.errors import MoonrakerRpcError, PrinterUnreachable
from kybercore.fleet.spools import read_spool
from kybercore.moonraker.client import MoonrakerClient

PETG = {
    "id": 7,
    "filament": {"name": "Basic PETG", "vendor": {"name": "Acme"}, "material": "PETG",
                 "color_hex": "2E7D32"},
    "remaining_weight": 612.0,
}  # fmt: skip


class _Moonraker:
    """Answers like a printer's Moonraker: ``spool_id`` and ``spool`` are answers or
    errors to raise."""

    name = "stub"

    def __init__(self, spool_id: object, answer: object = None) -> None:
        self.spool_id, self.answer = spool_id, answer

    async def active_spool_id(self) -> object:
        if isinstance(self.spool_id, Exception):
            raise self.spool_id
        return self.spool_id

    async def spoolman_spool(self, _spool_id: int) -> object:
        if isinstance(self.answer, Exception):
            raise self.answer
        return self.answer


@pytest.mark.parametrize(
    ("moonraker", "state"),
    [
        (_Moonraker(MoonrakerRpcError(404, "Not Found")), "absent"),
        (_Moonraker(MoonrakerRpcError(500, "boom")), "unknown"),
        (_Moonraker(PrinterUnreachable("down")), "unknown"),
        (_Moonraker(None), "none"),
        (_Moonraker(7, MoonrakerRpcError(503, "Spoolman down")), "unreachable"),
        (_Moonraker(7, {"message": "not a spool"}), "unreachable"),
    ],
)
async def test_no_spool_says_why(moonraker: _Moonraker, state: str) -> None:
    assert await read_spool(cast(MoonrakerClient, moonraker)) == (state, None)


async def test_an_active_spool_is_read() -> None:
    moonraker = _Moonraker(7, PETG)
    found, shown = await read_spool(cast(MoonrakerClient, moonraker))
    assert found == "active"
    assert shown == Spool(7, "Acme Basic PETG", "PETG", "2E7D32", 612.0)
