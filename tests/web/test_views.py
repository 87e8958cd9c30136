"""The page asks for full views of what it shows only (the tiles on screen, one printer's
page), and reads binary frames: slim summaries with full patches, and full views of printers
coming into view. The WebSocket is played by the test, as in test_scale.py."""

from __future__ import annotations

import json
import re
import time
from typing import Any

import pytest
from playwright.sync_api import Page, WebSocketRoute, expect

from tests.helpers import KyberCoreServer
from tests.web.conftest import ConsoleErrors
from tests.web.support import wait_in_page
from tests.web.test_scale import COUNT, connect, view

pytestmark = pytest.mark.browser


def views_asked(sockets: list[WebSocketRoute]) -> list[list[str] | None]:
    """Start recording the view messages the page sends on its socket."""
    asked: list[list[str] | None] = []

    def heard(message: str | bytes) -> None:
        frame = json.loads(message)
        if frame.get("type") == "view":
            asked.append(frame["printers"])

    sockets[0].on_message(heard)
    return asked


def next_view(page: Page, asked: list[list[str] | None], check: Any, what: str) -> list[str]:
    """Wait for a view message that passes ``check``."""

    def passing() -> list[str] | None:
        return next((ids for ids in asked if ids is not None and check(set(ids))), None)

    wait_in_page(page, lambda: passing() is not None, f"the page to ask for {what}")
    found = passing()
    assert found is not None
    return found


def test_the_page_asks_for_what_it_shows_and_reads_binary_frames(
    page: Page, kybercore_server: KyberCoreServer, console_errors: ConsoleErrors
) -> None:
    # The printers are the test's own: the printer page's REST reads find none of them.
    console_errors.expect(r"404 \(Not Found\) \[.*/api/printers/p250/")
    sockets = connect(page, kybercore_server.url)
    asked = views_asked(sockets)
    views = [view(i) for i in range(COUNT)]
    sockets[0].send(json.dumps({"type": "snapshot", "seq": 1, "printers": views}).encode())
    expect(page.locator(".tile")).to_have_count(COUNT)

    # The first screenful (and a margin), not the fleet.
    first = next_view(page, asked, lambda ids: "p000" in ids, "the first tiles")
    assert 0 < len(first) < COUNT // 2
    assert "p499" not in first

    # A binary delta: summaries of every changed printer, full patches of the shown ones.
    delta = {
        "type": "delta",
        "seq": 2,
        "removed": [],
        "printers": {"p000": {"job": {"progress": 0.5}}, "p498": {"job": {"progress": 0.25}}},
        "full": {"p000": {"extruder": {"temperature": 211.1}, "job": {"progress": 0.5}}},
    }
    sockets[0].send(json.dumps(delta).encode())
    expect(page.locator('.tile[data-id="p000"] .temp .value').first).to_have_text("211.1°")
    expect(page.locator('.tile[data-id="p000"] .pct')).to_have_text("50%")
    # A tile off screen follows its summary.
    expect(page.locator('.tile[data-id="p498"] .pct')).to_have_text("25%")

    # Scrolled to the end: the page asks for the last tiles instead of the first.
    page.locator('.tile[data-id="p499"]').scroll_into_view_if_needed()
    last = next_view(page, asked, lambda ids: "p499" in ids, "the last tiles")
    assert "p000" not in last
    entering = {**views[499], "extruder": {"temperature": 233.3, "target": 0.0, "power": 0.0}}
    sockets[0].send(json.dumps({"type": "views", "printers": [entering]}).encode())
    expect(page.locator('.tile[data-id="p499"] .temp .value').first).to_have_text("233.3°")

    # One printer's page: that printer alone.
    page.evaluate("location.hash = '#printer/p250'")
    next_view(page, asked, lambda ids: ids == {"p250"}, "the printer page's printer alone")


def test_a_page_opened_on_one_printer_names_it_when_it_connects(
    page: Page, kybercore_server: KyberCoreServer, console_errors: ConsoleErrors
) -> None:
    # The printer is the test's own: the printer page's REST reads find it not.
    console_errors.expect(r"404 \(Not Found\) \[.*/api/printers/p250/")
    sockets = connect(page, kybercore_server.url + "/#printer/p250")
    # Its first snapshot is that printer in full and summaries of the rest, not the fleet.
    assert sockets[0].url.endswith("/ws?view=p250")
    views = [view(i) for i in range(COUNT)]
    sockets[0].send(json.dumps({"type": "snapshot", "seq": 1, "printers": views}).encode())
    section = page.locator("#printer-view")
    expect(section.get_by_role("heading", level=1, name="Farm 250")).to_be_visible()


def test_the_printer_page_shows_how_old_a_quiet_printers_data_is(
    page: Page, kybercore_server: KyberCoreServer, console_errors: ConsoleErrors
) -> None:
    """Frames faked as the backend sends them: a printing printer whose Moonraker falls
    silent, which a real one does not do on demand. The age shows on the print card, and
    grows there with no frame arriving, as it does on the tiles."""
    console_errors.expect(r"404 \(Not Found\) \[.*/api/printers/p250/")
    sockets = connect(page, kybercore_server.url + "/#printer/p250")
    printing = view(250)
    assert printing["job"]["state"] == "printing"

    def heard(seq: int, seconds_ago: float) -> None:
        frame = [{**printing, "updated_at": time.time() - seconds_ago}]
        sockets[0].send(json.dumps({"type": "snapshot", "seq": seq, "printers": frame}))

    heard(1, 0)
    card = page.locator("#pp-job")
    expect(card.locator(".pp-job-file")).to_have_text("part_12.gcode")
    stale = card.locator(".stale")
    expect(stale).to_be_hidden()
    heard(2, 125)
    expect(stale).to_have_text("Data 2 min old")
    expect(card).to_have_class(re.compile(r"\bis-stale\b"))
    # Heard 8 s ago and nothing since: within a few seconds it is 10 s old, and says so.
    heard(3, 8)
    expect(stale).to_be_hidden()
    expect(stale).to_have_text(re.compile(r"^Data 1\d s old$"), timeout=15_000)
    heard(4, 0)
    expect(stale).to_be_hidden()
    expect(card).not_to_have_class(re.compile(r"\bis-stale\b"))
