""" "Find printers" in Chromium: Moonraker servers announced over mDNS on loopback (a real
python-zeroconf announcer sending what Moonraker's [zeroconf] sends, for real virtual
printers: KyberCore's server browses the host's loopback, where Moonraker's own would
multicast on the LAN too; tests/fleet/test_discovery.py browses Moonraker's own in a network
namespace), one already in the fleet, one added with one click and online at once."""

from __future__ import annotations

import socket
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest
from playwright.sync_api import Page, expect
from zeroconf import ServiceInfo, Zeroconf

from kybercore.fleet.discovery import SERVICE_TYPE
from kybercore.sim.stack import PrinterStack
from tests.conftest import MDNS
from tests.helpers import KyberCoreServer, wait_until
from tests.web.support import open_fleet, tile

pytestmark = pytest.mark.browser


def announce(zc: Zeroconf, name: str, url: str, host: str) -> None:
    port = int(url.rsplit(":", 1)[1])
    zc.register_service(
        ServiceInfo(
            SERVICE_TYPE,
            f"{name} @ {host}.{SERVICE_TYPE}",  # as Moonraker names itself
            addresses=[socket.inet_aton("127.0.0.1")],
            port=port,
            properties={"uuid": name, "https_port": "", "version": "v0.9.3", "route_prefix": ""},
            server=f"{host}.local.",
        )
    )


@pytest.fixture
def announcer() -> Iterator[Zeroconf]:
    # Made in a thread of its own: Playwright's sync API keeps an event loop in this one,
    # which Zeroconf would adopt and never see run; elsewhere it starts its own loop.
    with ThreadPoolExecutor(1) as pool:
        zc = pool.submit(Zeroconf, interfaces=[MDNS]).result()
    yield zc
    zc.unregister_all_services()
    zc.close()


def test_find_printers_lists_them_and_adds_one_in_one_click(
    page: Page,
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    announcer: Zeroconf,
    own_printer: PrinterStack,
    fleet_stacks: list[PrinterStack],
) -> None:
    announce(announcer, "Moonraker-aaaa1111", fleet_stacks[0].url, "fleet-a-host")
    announce(announcer, "Moonraker-bbbb2222", own_printer.url, "kc-lab")
    open_fleet(page, kybercore_server.url)
    try:
        page.get_by_role("button", name="Find printers").click()
        dialog = page.get_by_role("dialog", name="Find printers on the network")
        expect(dialog.get_by_role("status").first).to_have_text(
            "2 Moonraker servers answered.", timeout=20_000
        )
        known = dialog.locator(f'.find-item[data-url="{fleet_stacks[0].url}"]')
        expect(known).to_contain_text("Added as fleet-a")
        expect(known.get_by_role("button")).to_have_count(0)
        new = dialog.locator(f'.find-item[data-url="{own_printer.url}"]')
        expect(new).to_contain_text("Moonraker v0.9.3")
        new.get_by_role("button", name="Add Moonraker-bbbb2222 @ kc-lab").click()
        expect(new).to_contain_text("Added as kc-lab", timeout=30_000)
        dialog.get_by_role("button", name="Close").first.click()
        expect(tile(page, "kc-lab")).to_be_visible()
        wait_until(
            lambda: api.get("/api/printers/kc-lab").json()["connection"] == "online",
            timeout=60,
            what="kc-lab online",
        )
    finally:
        api.delete("/api/printers/kc-lab")  # the other tests expect three printers
    expect(page.locator(".tile")).to_have_count(3)
