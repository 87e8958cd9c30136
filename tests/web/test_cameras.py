"""The camera wall and the printer page's webcam, in Chromium over the virtual printers'
real webcams (relayed by KyberCore): a picture per printer, one snapshot request at a time,
a live stream only on the printer page, closed when the page is left."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from playwright.sync_api import Page, Request, expect

from tests.helpers import KyberCoreServer, wait_until
from tests.web.support import ARTIFACTS, open_fleet, tile

pytestmark = pytest.mark.browser

SNAPSHOT = "/webcams/kybercam/snapshot"


def test_the_wall_refreshes_one_snapshot_at_a_time(
    page: Page, kybercore_server: KyberCoreServer
) -> None:
    in_flight: set[Request] = set()
    most = 0
    done = 0

    def started(request: Request) -> None:
        nonlocal most
        if SNAPSHOT in request.url:
            in_flight.add(request)
            most = max(most, len(in_flight))

    def ended(request: Request) -> None:
        nonlocal done
        if request in in_flight:
            in_flight.discard(request)
            done += 1

    page.on("request", started)
    page.on("requestfinished", ended)
    page.on("requestfailed", ended)
    open_fleet(page, kybercore_server.url)
    page.get_by_role("link", name="Cameras").click()
    wall = page.locator("#cameras-view")
    expect(wall.locator(".cam-tile")).to_have_count(3)
    expect(wall.locator(".cam-img[src]")).to_have_count(3)
    # Every picture is a real JPEG the browser decoded.
    widths = wall.locator(".cam-img").evaluate_all("imgs => imgs.map(i => i.naturalWidth)")
    assert all(w > 0 for w in widths), widths
    # Two rounds and more (Playwright delivers events while it is waiting on the page).
    while done < 7:
        page.wait_for_event("requestfinished", timeout=30_000)
    assert most == 1, f"{most} snapshot requests were in flight at once"
    assert not [r for r in in_flight if "/stream" in r.url]
    # A tile leads to its printer's page.
    wall.locator('.cam-tile[data-id="fleet-a"] .name-link').click()
    expect(page.get_by_role("heading", level=1, name="Printer A")).to_be_visible()


def test_the_printer_page_streams_and_stops_when_left(
    page: Page, kybercore_server: KyberCoreServer
) -> None:
    open_fleet(page, kybercore_server.url)
    tile(page, "fleet-b").get_by_role("link", name="Printer B").click()
    webcam = page.locator("#printer-webcam")
    image = webcam.get_by_role("img", name="Printer B: webcam kybercam")
    expect(image).to_have_attribute("src", "/api/printers/fleet-b/webcams/kybercam/stream")
    wait_until(lambda: image.evaluate("i => i.naturalWidth") > 0, what="a first frame")
    page.go_back()
    expect(webcam).to_be_hidden()
    expect(webcam.locator("img")).to_have_count(0)


def test_the_wall_in_spanish_on_a_phone(
    new_page: Callable[..., Page], kybercore_server: KyberCoreServer
) -> None:
    phone = new_page(width=390, height=844, locale="es-ES", color_scheme="light")
    open_fleet(phone, kybercore_server.url)
    phone.goto(kybercore_server.url + "/#cameras")
    wall = phone.locator("#cameras-view")
    expect(wall.get_by_role("heading", name="Cámaras")).to_be_visible()
    expect(wall.locator(".cam-img[src]")).to_have_count(3)
    width = phone.evaluate("document.documentElement.scrollWidth")
    assert width <= 390, f"the wall scrolls sideways: {width} px"
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    phone.screenshot(path=str(ARTIFACTS / "camera_wall_phone.png"), full_page=True)
    wide = new_page(width=1440, height=900)
    open_fleet(wide, kybercore_server.url)
    wide.goto(kybercore_server.url + "/#cameras")
    expect(wide.locator(".cam-img[src]")).to_have_count(3)
    wide.screenshot(path=str(ARTIFACTS / "camera_wall.png"))
