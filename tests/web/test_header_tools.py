"""The header's farm tools in Chromium over real virtual printers: utilisation today from
the ledger, compact tiles that fit 50 printers on a 1080p screen, and browser notifications
(opt-in) when a printer stops while the page is in the background."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from datetime import datetime

import httpx
import pytest
from playwright.sync_api import Page, expect

from tests.helpers import KyberCoreServer, wait_until
from tests.web.support import open_fleet, tile

pytestmark = pytest.mark.browser

# The operating system's notification centre is not in a headless browser: a fake
# Notification records what the page asks it to show, and says permission was granted.
FAKE_NOTIFICATION = """
window.__notes = [];
window.Notification = class {
  constructor(title, options) { window.__notes.push({ title, body: options?.body || "" }); }
  static permission = "granted";
  static requestPermission() { return Promise.resolve("granted"); }
};
"""
# The page in the background: another window has the focus.
AWAY = """
Object.defineProperty(document, "hidden", { get: () => true });
Object.defineProperty(document, "visibilityState", { get: () => "hidden" });
document.hasFocus = () => false;
"""


def test_utilisation_today_is_the_ledgers(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    open_fleet(page, kybercore_server.url)
    figure = page.locator("#utilisation")
    expect(figure).to_have_text(re.compile(r"^Utilisation today: \d+ %$"))
    midnight = datetime.now().astimezone().replace(hour=0, minute=0, second=0, microsecond=0)
    rows = api.get(
        "/api/stats", params={"group_by": "printer", "from": midnight.isoformat()}
    ).json()["rows"]
    shares = [r["utilisation"] for r in rows if r["utilisation"] is not None]
    expected = round(100 * sum(shares) / len(shares))
    shown = int(re.findall(r"\d+", figure.inner_text())[0])
    assert abs(shown - expected) <= 1, (shown, expected)


def test_compact_tiles_fit_fifty_printers_on_a_1080p_screen(
    new_page: Callable[..., Page], kybercore_server: KyberCoreServer
) -> None:
    page = new_page(width=1920, height=1080)
    open_fleet(page, kybercore_server.url)
    full = tile(page, "fleet-a").bounding_box()
    page.get_by_role("button", name="Compact").click()
    expect(page.get_by_role("button", name="Compact")).to_have_attribute("aria-pressed", "true")
    box = tile(page, "fleet-a").bounding_box()
    grid = page.locator("#grid").bounding_box()
    assert full is not None
    assert box is not None
    assert grid is not None
    assert box["height"] < full["height"]
    gap = 6  # the compact grid's gap (fleet.css)
    columns = math.floor((grid["width"] + gap) / (box["width"] + gap))
    rows = math.ceil(50 / columns)
    bottom = grid["y"] + rows * box["height"] + (rows - 1) * gap
    assert bottom <= 1080, f"{columns} columns × {rows} rows end at {bottom:.0f} px"
    page.reload()  # remembered
    expect(page.get_by_role("button", name="Compact")).to_have_attribute("aria-pressed", "true")


def test_a_stopped_printer_notifies_a_browser_in_the_background(
    new_page: Callable[..., Page], kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    page = new_page()
    page.add_init_script(FAKE_NOTIFICATION + AWAY)
    open_fleet(page, kybercore_server.url)
    toggle = page.get_by_role("button", name="Browser notifications")
    toggle.click()
    expect(toggle).to_have_attribute("aria-pressed", "true")
    assert page.evaluate("window.__notes.length") == 0  # nothing from the past on load
    api.post("/api/printers/fleet-c/actions/emergency_stop", json={})
    wait_until(lambda: page.evaluate("window.__notes.length") > 0, timeout=30, what="a note")
    notes = page.evaluate("window.__notes")
    assert [n["title"] for n in notes] == ["Printer C"], notes
    api.post("/api/printers/fleet-c/actions/firmware_restart", json={})
    wait_until(
        lambda: api.get("/api/printers/fleet-c").json()["klippy_state"] == "ready",
        timeout=60,
        what="fleet-c ready again",
    )
    page.reload()  # a reload: the shutdown is past, and the choice remembered
    open_fleet(page, kybercore_server.url)
    expect(page.get_by_role("button", name="Browser notifications")).to_have_attribute(
        "aria-pressed", "true"
    )
    assert page.evaluate("window.__notes.length") == 0
