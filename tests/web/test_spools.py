"""The active Spoolman spool on a printer's tile and page, and the Spools view (#spools), in
Chromium: a real printer with [spoolman] in its moonraker.conf, on a fake Spoolman
(tests/fake_spoolman.py says why), next to a printer without Spoolman."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import Page, expect

from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import write_printers
from kybercore.sim.stack import PrinterStack, free_port
from tests.fake_spoolman import FakeSpoolman, printer_with_spoolman, spool
from tests.helpers import KyberCoreServer

pytestmark = pytest.mark.browser


PETG, LOW_PLA = 7, 8


@dataclass(frozen=True)
class SpoolFleet:
    server: KyberCoreServer
    stack: PrinterStack
    """The printer with [spoolman] ("mk4")."""

    def set_active(self, spool_id: int) -> None:
        """What Mainsail does when the user picks a spool."""
        answer = httpx.post(f"{self.stack.url}/server/spoolman/spool_id",
                            json={"spool_id": spool_id})  # fmt: skip
        assert answer.status_code == 200, answer.text


@pytest.fixture
def spool_fleet(
    start_stack: Callable[..., PrinterStack], printer: PrinterStack, tmp_path: Path
) -> Iterator[SpoolFleet]:
    spoolman = FakeSpoolman(
        [spool(PETG, "PETG", "2E7D32", 612.0), spool(LOW_PLA, "PLA", "F9A825", 42.0)]
    )
    spoolman.start()
    stack = printer_with_spoolman(start_stack, "spool-tile", spoolman)
    fleet = SpoolFleet(KyberCoreServer(tmp_path / "printers.json", free_port()), stack)
    fleet.set_active(PETG)
    write_printers(
        tmp_path / "printers.json",
        [
            PrinterConfig(id="mk4", name="MK4", moonraker_url=stack.url),
            # The session's shared printer: no [spoolman] in its moonraker.conf.
            PrinterConfig(id="plain", name="Plain", moonraker_url=printer.url),
        ],
    )
    fleet.server.start()
    fleet.server.wait_online(2)
    yield fleet
    fleet.server.stop()
    stack.stop()
    spoolman.stop()


def test_the_tile_and_the_page_show_the_spool(page: Page, spool_fleet: SpoolFleet) -> None:
    spool_server = spool_fleet.server
    page.goto(spool_server.url)
    badge = page.locator('.tile[data-id="mk4"] .badge.spool')
    expect(badge).to_have_text("PETG · 612 g left")
    expect(badge).to_have_attribute("title", "Spoolman spool #7: Acme Basic PETG")
    color = badge.locator(".swatch").evaluate("e => getComputedStyle(e).backgroundColor")
    assert color == "rgb(46, 125, 50)"
    page.locator('.tile[data-id="mk4"] .name-link').click()
    expect(page.locator("#pp-extruder .badge.spool")).to_have_text("PETG · 612 g left")


def test_the_spools_view_maps_each_spool_to_its_printer_live(
    page: Page, spool_fleet: SpoolFleet
) -> None:
    page.goto(f"{spool_fleet.server.url}/#spools")
    view = page.locator("#spools-view")
    expect(view.locator("h2")).to_have_text("Spools")
    row = view.locator(f'tr[data-spool="{PETG}"]')
    expect(row).to_contain_text("Acme Basic PETG")
    expect(row.locator("td").nth(1)).to_have_text("PETG")
    expect(row.locator("td").nth(2)).to_have_text("612 g")
    expect(row.locator(".swatch")).to_have_attribute("aria-label", "Colour #2E7D32")
    expect(row.locator("a.name-link")).to_have_attribute("href", "#printer/mk4")
    plain = view.locator('.spools-without li[data-id="plain"]')
    expect(plain).to_contain_text("no Spoolman: [spoolman] is not in its moonraker.conf")

    # Another spool picked in Mainsail: the map follows, without a reload; a low one says so.
    spool_fleet.set_active(LOW_PLA)
    low = view.locator(f'tr[data-spool="{LOW_PLA}"]')
    expect(low.locator("td").nth(2)).to_have_text("42 g Low")
    expect(view.locator(f'tr[data-spool="{PETG}"]')).to_have_count(0)
    expect(view.locator("header p")).to_have_text("1 Spoolman spool on a printer. · 1 running low")
    color = low.locator(".swatch").evaluate("e => getComputedStyle(e).backgroundColor")
    assert color == "rgb(249, 168, 37)"

    # The printer's name leads to its page.
    low.locator("a.name-link").click()
    expect(page).to_have_url(f"{spool_fleet.server.url}/#printer/mk4")
    expect(page.locator("#printer-view")).to_be_visible()

    # In Spanish, built before and after the switch.
    page.goto(f"{spool_fleet.server.url}/#spools")
    page.select_option("#lang", "es")
    expect(view.locator("h2")).to_have_text("Bobinas")
    expect(low.locator("td").nth(2)).to_have_text("42 g Poco filamento")
    expect(low.locator(".swatch")).to_have_attribute("aria-label", "Color #F9A825")
    expect(view.locator("th")).to_have_text(["Bobina", "Material", "Restante", "Impresora"])
    expect(plain).to_contain_text("sin Spoolman: su moonraker.conf no tiene [spoolman]")
    expect(page.locator('nav.pages a[data-page="spools"]')).to_have_text("Bobinas")
    expect(page.locator('nav.pages a[data-page="spools"]')).to_have_attribute(
        "aria-current", "page"
    )
