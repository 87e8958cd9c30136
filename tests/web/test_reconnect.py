"""The dashboard notices a dead backend, says so, and recovers by itself."""

from __future__ import annotations

import pytest
from playwright.sync_api import Page, expect

from tests.helpers import KyberCoreServer
from tests.web.conftest import ConsoleErrors
from tests.web.support import FLEET, open_fleet, tile

pytestmark = pytest.mark.browser


def test_stopping_the_backend_shows_the_banner_and_restarting_clears_it(
    page: Page, kybercore_server: KyberCoreServer, console_errors: ConsoleErrors
) -> None:
    sockets: list[str] = []
    page.on("websocket", lambda ws: sockets.append(ws.url))
    open_fleet(page, kybercore_server.url)
    page.evaluate("window.__sameDocument = true")
    banner = page.locator("#banner")
    expect(banner).to_be_hidden()
    expect(page.locator("#live")).to_have_text("Live")

    # While the backend is down, the browser's reconnect attempts are refused: expected.
    console_errors.expect(r"ERR_CONNECTION_REFUSED")
    kybercore_server.stop()
    try:
        expect(banner).to_be_visible(timeout=20_000)
        expect(banner).to_have_attribute("role", "alert")
        expect(banner).to_contain_text("Connection to KyberCore lost.")
        expect(banner).to_contain_text("The data shown is from")
        expect(page.locator("#live")).to_have_text("Disconnected")
        # The last known fleet stays on screen, marked as possibly out of date.
        expect(page.locator(".tile")).to_have_count(3)
        expect(page.locator("body")).to_have_class("is-offline")
    finally:
        kybercore_server.start()
    kybercore_server.wait_online(len(FLEET), timeout=60)

    expect(banner).to_be_hidden(timeout=15_000)
    expect(page.locator("#live")).to_have_text("Live")
    # Resynced from the new server's snapshot, on the same page.
    for printer_id in FLEET:
        expect(tile(page, printer_id).locator(".badge.conn")).to_have_text("Online", timeout=20_000)
        expect(tile(page, printer_id).locator(".pill")).to_have_text("Ready")
    assert page.evaluate("window.__sameDocument") is True
    # The first socket asked for every printer in full; the reconnects named the tiles on
    # screen, so their first snapshot was already the view's.
    assert sockets[0].endswith("/ws")
    assert sockets[-1].endswith("/ws?view=" + "%2C".join(sorted(FLEET)))
