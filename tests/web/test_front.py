"""The dashboard against a front on NATS (2 ingest workers) behaves as against ``serve``:
the same tiles, live, and actions that reach the printers through their workers."""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import Page, expect

from kybercore.sim.stack import PrinterStack
from tests.scale.cluster import Cluster, fresh_cluster
from tests.web.support import expect_ready_tiles, open_fleet, tile

pytestmark = pytest.mark.browser


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
