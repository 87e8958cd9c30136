"""A restarted Moonraker is back in KyberCore soon after it is ready again: a real Moonraker
+ Klippy printer, its Moonraker stopped for 1 to 10 s, ten times."""

from __future__ import annotations

from collections.abc import AsyncIterator

import httpx
import pytest
from bench.comeback import Timed, comeback, summary

from kybercore.moonraker.client import MoonrakerClient
from kybercore.sim.stack import PrinterStack
from tests.helpers import wait_for

pytestmark = [pytest.mark.integration, pytest.mark.timeout(600)]

OUTAGES = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0)
BACK_WITHIN = 10.0
"""Promise: shown ready again within 2 s (p95) of Moonraker answering ready; the bound is
5x that. Measured: median 0.24 s, p95 1.0 s (before the fix, refused connections backed
off to 4-8 s: median 1.24 s, p95 3.5 s here); bench/comeback.py measures the p95."""


@pytest.fixture
async def watched(
    own_printer: PrinterStack, http: httpx.AsyncClient
) -> AsyncIterator[tuple[MoonrakerClient, Timed]]:
    timed = Timed()
    client = MoonrakerClient(own_printer.url, http, name="own", on_event=timed)
    client.start()
    await wait_for(lambda: timed.ready_at(0) is not None, what="the first ready")
    yield client, timed
    await client.close()


async def test_back_soon_after_moonraker_restarts_with_outages_of_1_to_10_s(
    own_printer: PrinterStack, watched: tuple[MoonrakerClient, Timed]
) -> None:
    client, timed = watched
    late = [await comeback(own_printer, client, timed, outage, BACK_WITHIN) for outage in OUTAGES]
    figures = summary(late)
    print(
        "\nback after Moonraker was ready, per outage: "
        + ", ".join(f"{o:g} s: {t:.2f}" for o, t in zip(OUTAGES, late, strict=True))
        + f"\nmedian {figures['median']} s, p95 {figures['p95']} s, max {figures['max']} s"
    )
    assert max(late) < BACK_WITHIN
