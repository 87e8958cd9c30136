"""The active Spoolman spool on a printer's tile and page, in Chromium: a real printer with
[spoolman] in its moonraker.conf, on a fake Spoolman (tests/fake_spoolman.py says why)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
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


@pytest.fixture
def spool_server(
    start_stack: Callable[..., PrinterStack], tmp_path: Path
) -> Iterator[KyberCoreServer]:
    spoolman = FakeSpoolman([spool(7, "PETG", "2E7D32", 612.0)])
    spoolman.start()
    stack = printer_with_spoolman(start_stack, "spool-tile", spoolman)
    httpx.post(f"{stack.url}/server/spoolman/spool_id", json={"spool_id": 7})
    printers = tmp_path / "printers.json"
    write_printers(printers, [PrinterConfig(id="mk4", name="MK4", moonraker_url=stack.url)])
    server = KyberCoreServer(printers, free_port())
    server.start()
    server.wait_online(1)
    yield server
    server.stop()
    stack.stop()
    spoolman.stop()


def test_the_tile_and_the_page_show_the_spool(page: Page, spool_server: KyberCoreServer) -> None:
    page.goto(spool_server.url)
    badge = page.locator('.tile[data-id="mk4"] .badge.spool')
    expect(badge).to_have_text("PETG · 612 g left")
    expect(badge).to_have_attribute("title", "Spoolman spool #7: Acme Basic PETG")
    color = badge.locator(".swatch").evaluate("e => getComputedStyle(e).backgroundColor")
    assert color == "rgb(46, 125, 50)"
    page.locator('.tile[data-id="mk4"] .name-link').click()
    expect(page.locator("#pp-extruder .badge.spool")).to_have_text("PETG · 612 g left")
