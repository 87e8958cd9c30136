"""Selecting printers by state: a finished or cancelled printer may still hold its part, so
it is "finished", not "ready", and "Select idle" leaves it out."""

from __future__ import annotations

import httpx
import pytest
from playwright.sync_api import Page, expect

from tests.helpers import KyberCoreServer, wait_until
from tests.web.support import open_fleet, slow_print, tile

pytestmark = pytest.mark.browser


@pytest.fixture
def finished_fleet_c(api: httpx.Client) -> None:
    """fleet-a with a print just finished (the suite's fleet reset puts it back to standby)."""
    answer = api.post(
        "/api/printers/fleet-a/files",
        files={"file": ("selection-test.gcode", slow_print(2), "application/octet-stream")},
        data={"start": "true", "confirm": "true"},
    )
    assert answer.status_code == 201, answer.text
    wait_until(
        lambda: api.get("/api/printers/fleet-a").json()["job"]["state"] == "complete",
        timeout=60,
        what="fleet-a complete",
    )


@pytest.mark.usefixtures("finished_fleet_c")
def test_a_finished_printer_is_not_idle(page: Page, kybercore_server: KyberCoreServer) -> None:
    open_fleet(page, kybercore_server.url)
    card = tile(page, "fleet-a")
    expect(card.locator(".pill")).to_have_text("Complete")
    expect(card).to_have_attribute("data-status", "done")
    expect(page.locator(".count-chip[data-group=done] strong")).not_to_have_text("0")

    page.locator("[data-select-group=ready]").click()
    expect(page.get_by_role("checkbox", name="Select Printer A")).not_to_be_checked()
    selected = page.locator(".tile:has(input.select:checked)")
    for index in range(selected.count()):
        expect(selected.nth(index).locator(".pill")).to_have_text("Ready")

    # The state filter has them under their own name.
    page.select_option("#filter-state", "done")
    expect(page.locator(".tile:visible")).to_have_count(1)
    expect(tile(page, "fleet-a")).to_be_visible()
