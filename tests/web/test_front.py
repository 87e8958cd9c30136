"""The dashboard against a front on NATS (2 ingest workers) behaves as against ``serve``:
the same tiles, live, actions that reach the printers through their workers, and the
printer page's live webcam."""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import Page, expect

from kybercore.sim.stack import PrinterStack
from tests.helpers import wait_until
from tests.scale.cluster import Cluster, fresh_cluster
from tests.web.support import expect_ready_tiles, open_fleet, tile

pytestmark = pytest.mark.browser

SAY_WITHIN_MS = 10_000
"""nats-py notices a dead connection within ~2 pings of 2 s; the front checks 4 times a s."""
BACK_WITHIN_MS = 60_000
"""The front reconnects within a second; JetStream may take a few to recover."""


@pytest.fixture
def cluster(fleet_stacks: list[PrinterStack], tmp_path: Path) -> Iterator[Cluster]:
    with fresh_cluster(fleet_stacks, tmp_path) as started:
        yield started


def test_the_overview_on_a_front_is_live_and_acts(
    new_page: Callable[..., Page], cluster: Cluster
) -> None:
    page = new_page()
    # The header's queue figures (/api/jobs, /api/gates, /api/queue) come from the front's
    # queue as from serve's: no console error is allowed.
    open_fleet(page, cluster.front.url)
    expect_ready_tiles(page)
    expect(page.locator(".count-chip[data-group=ready] strong")).to_have_text("3")

    # An action through the front runs on the printer's worker; the tile follows.
    url = f"{cluster.front.url}/api/printers/fleet-c/actions/set_temperature"
    answer = httpx.post(url, json={"extruder": 60}, timeout=30)
    assert answer.status_code == 200, answer.text
    hotend = tile(page, "fleet-c").locator(".temp").first
    expect(hotend.locator(".target")).to_have_text("/ 60°")
    expect(hotend).to_have_class(re.compile(r"\bheating\b"))
    answer = httpx.post(url, json={"extruder": 0}, timeout=30)
    assert answer.status_code == 200, answer.text
    expect(hotend).not_to_have_class(re.compile(r"\bheating\b"))

    # The printer page's webcam streams live through the front (the owner relays it), as
    # on serve: no fallback to snapshots.
    tile(page, "fleet-b").get_by_role("link", name="Printer B").click()
    webcam = page.locator("#printer-webcam")
    image = webcam.get_by_role("img", name="Printer B: webcam kybercam")
    expect(image).to_have_attribute("src", "/api/printers/fleet-b/webcams/kybercam/stream")
    wait_until(lambda: image.evaluate("i => i.naturalWidth") > 0, what="a first frame")
    expect(webcam.locator(".webcam-note")).to_have_text("")


def test_a_front_cut_off_from_its_broker_says_so_once_for_the_fleet(
    new_page: Callable[..., Page], cluster: Cluster
) -> None:
    # Every tile goes stale at once: one banner says it is the front that cannot hear the
    # printers, not the printers that failed; a page opened meanwhile says it too.
    page = new_page()
    open_fleet(page, cluster.front.url)
    expect_ready_tiles(page)
    banner = page.locator("#broker-banner")
    expect(banner).to_be_hidden()
    cluster.broker.stop()
    began = time.monotonic()
    expect(banner).to_be_visible(timeout=SAY_WITHIN_MS)
    print(f"banner shown {time.monotonic() - began:.2f} s after the broker stopped")
    expect(banner).to_contain_text("lost its message broker (NATS)")
    cut_off = re.compile(r"\bis-cut-off\b")  # the tiles dimmed, as for a lost socket
    expect(page.locator("body")).to_have_class(cut_off)
    page.reload()
    expect(banner).to_be_visible(timeout=SAY_WITHIN_MS)
    expect(page.locator("#banner")).to_be_hidden()  # the page's own socket is fine
    cluster.broker.start(port=cluster.broker.port)
    expect(banner).to_be_hidden(timeout=BACK_WITHIN_MS)
    expect(page.locator("body")).not_to_have_class(cut_off)
    wait_until(lambda: cluster.all_fresh(3), BACK_WITHIN_MS / 1000, "every printer fresh again")
    expect_ready_tiles(page)
