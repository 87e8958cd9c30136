"""A tile says when a printer's limits are unknown, in English and Spanish."""

from __future__ import annotations

from collections.abc import Callable

import httpx
import pytest
from playwright.sync_api import Page, expect

from tests.hardening.faults import standin_process
from tests.helpers import KyberCoreServer, wait_until
from tests.web.support import open_fleet, tile

pytestmark = pytest.mark.browser


def test_a_tile_says_the_limits_are_unknown(
    new_page: Callable[..., Page], kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    # FAULT-INJECTION stand-in, not Moonraker: its configfile query always fails, which a
    # real Klippy cannot be made to do on demand.
    with standin_process("healthy") as standin:
        body = {"id": "no-limits", "name": "No limits", "moonraker_url": standin.url}
        assert api.post("/api/printers", json=body).status_code == 201
        try:
            wait_until(
                lambda: api.get("/api/printers/no-limits").json()["limits"] == "unknown",
                what="limits unknown",
            )
            for locale, text in (("en-US", "Limits unknown"), ("es-ES", "Límites desconocidos")):
                page = new_page(locale=locale)
                open_fleet(page, kybercore_server.url, count=4)
                badge = tile(page, "no-limits").locator(".badge.limits")
                expect(badge).to_have_text(text)
                expect(badge).to_have_attribute("data-limits", "unknown")
                expect(tile(page, "fleet-a").locator(".badge.limits")).to_be_hidden()
        finally:
            api.delete("/api/printers/no-limits")
