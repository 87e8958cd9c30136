"""Helpers of the browser tests: set the real printers up through the REST API, wait for
the dashboard, find tiles."""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Final

import httpx
from playwright.sync_api import Locator, Page, expect

from tests.helpers import KyberCoreServer, travel_gcode, wait_until

ARTIFACTS = Path(__file__).resolve().parents[1] / "artifacts"
DOCS = Path(__file__).resolve().parents[2] / "docs"
FLEET = ("fleet-a", "fleet-b", "fleet-c")
BUSY = ("printing", "paused")
SAMPLES = Path(__file__).resolve().parents[2] / "src/kybercore/sim/samples"
SAMPLE = SAMPLES / "calibration_cube_20mm_pla.gcode"
# axe-core's script (pinned in package-lock.json, installed by `npm ci`), run in the page.
AXE = Path(__file__).resolve().parents[2] / "node_modules" / "axe-core" / "axe.min.js"


@functools.cache
def _axe_script() -> str:
    return AXE.read_text()


AXE_TAGS: Final = ["wcag2a", "wcag2aa", "wcag21a", "wcag21aa", "wcag22aa", "best-practice"]
BLOCKING: Final = ("serious", "critical")
ALSO_BLOCKING: Final = ("landmark-one-main", "heading-order")
"""Moderate rules that block too: every screen has one main landmark, headings in order."""


def axe_violations(page: Page) -> list[dict[str, Any]]:
    """axe-core's blocking violations on the page as it is: each with its rule, impact and
    the first elements it names, so a failure says what to fix."""
    inject_axe(page)
    result = page.evaluate(
        "async (tags) => (await axe.run(document, {runOnly: {type: 'tag', values: tags}}))"
        ".violations.map(v => ({id: v.id, impact: v.impact, help: v.help,"
        " nodes: v.nodes.slice(0, 3).map(n => n.target.join(' ') + ' :: ' + n.failureSummary)}))",
        AXE_TAGS,
    )
    return [v for v in result if v["impact"] in BLOCKING or v["id"] in ALSO_BLOCKING]


def inject_axe(page: Page) -> None:
    """Put axe-core in ``page`` unless it is there already: the script is 654 kB, read once
    per run and evaluated once per page (through the DevTools protocol, so the page's CSP,
    script-src 'self', stays on)."""
    if not page.evaluate("typeof axe !== 'undefined'"):
        page.evaluate(_axe_script())


def make_idle(server: KyberCoreServer, api: httpx.Client) -> None:
    """Leave fleet-a/b/c online, Klippy ready, not printing, heaters off, job forgotten."""
    server.wait_online(len(FLEET), timeout=60)
    for printer_id in FLEET:
        view = api.get(f"/api/printers/{printer_id}").json()
        if view["job"]["state"] in BUSY:
            api.post(f"/api/printers/{printer_id}/actions/cancel", json={})
        if (view["extruder"]["target"] or 0) > 0 or (view["bed"]["target"] or 0) > 0:
            api.post(
                f"/api/printers/{printer_id}/actions/set_temperature",
                json={"extruder": 0, "bed": 0},
            )

    def idle(printer_id: str) -> bool:
        view = api.get(f"/api/printers/{printer_id}").json()
        return view["klippy_state"] == "ready" and view["job"]["state"] not in BUSY

    wait_until(lambda: all(idle(p) for p in FLEET), timeout=30, what="fleet idle")
    # Forget the last job (cancelled, complete): tiles start from "Ready", no file shown.
    for printer_id in FLEET:
        if api.get(f"/api/printers/{printer_id}").json()["job"]["state"] != "standby":
            answer = api.post(
                f"/api/printers/{printer_id}/gcode", json={"script": "SDCARD_RESET_FILE"}
            )
            assert answer.status_code == 200, answer.text


def wait_in_page(
    page: Page, predicate: Callable[[], bool], what: str, timeout: float = 10.0
) -> None:
    """Wait until ``predicate()`` is true when it reads what Playwright's callbacks collect
    (routed sockets, their messages). The sync API delivers those only while a call of
    ``page`` runs, so this waits inside one; ``tests.helpers.wait_until`` would not."""
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, f"timed out after {timeout:g} s waiting for {what}"
        page.wait_for_timeout(50)  # poll: lets Playwright deliver the callbacks


def thumbnail_block() -> str:
    """The PrusaSlicer thumbnail comment block of a sample file."""
    lines = SAMPLE.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("; thumbnail begin"))
    end = next(i for i, line in enumerate(lines) if line.startswith("; thumbnail end"))
    return "\n".join(lines[start : end + 1])


def slow_print(moves: int = 60) -> bytes:
    """A travel-only file (no heating) with a thumbnail: slow enough to pause and cancel."""
    header, _, rest = travel_gcode(moves).decode().partition("\n")
    return f"{header}\n;\n{thumbnail_block()}\n\n{rest}".encode()


def start_print(api: httpx.Client, printer_id: str, filename: str, moves: int = 60) -> None:
    """Upload ``filename`` and start printing it, through the REST API."""
    answer = api.post(
        f"/api/printers/{printer_id}/files",
        files={"file": (filename, slow_print(moves), "application/octet-stream")},
        data={"start": "true", "confirm": "true"},
    )
    assert answer.status_code == 201, answer.text
    wait_until(
        lambda: api.get(f"/api/printers/{printer_id}").json()["job"]["state"] == "printing",
        what=f"{printer_id} printing",
    )


def open_fleet(page: Page, url: str, count: int = 3) -> None:
    """Load the dashboard and wait until it is live with ``count`` tiles."""
    page.goto(url)
    page.locator("#live[data-state=live]").wait_for()
    expect(page.locator(".tile")).to_have_count(count)


def tile(page: Page, printer_id: str) -> Locator:
    return page.locator(f'.tile[data-id="{printer_id}"]')


FLEET_NAMES = (("fleet-a", "Printer A"), ("fleet-b", "Printer B"), ("fleet-c", "Printer C"))
"""The shared fleet's printers and their names (tests/conftest.py)."""


def expect_ready_tiles(page: Page) -> None:
    """The shared fleet's three tiles show their names, Virtual · Lab, and ready."""
    for printer_id, name in FLEET_NAMES:
        card = tile(page, printer_id)
        expect(card.locator(".name")).to_have_text(name)
        expect(card.locator(".meta")).to_have_text("Virtual · Lab")
        expect(card.locator(".pill")).to_have_text("Ready")
        expect(card.locator(".badge.conn")).to_have_text("Online")
        expect(card.locator(".badge.klippy")).to_have_text("Klipper ready")
