"""The overview shows the real fleet live, in English and Spanish, and looks right."""

from __future__ import annotations

import os
import re
import shutil
from collections.abc import Callable

import httpx
import pytest
from playwright.sync_api import Page, expect

from tests.helpers import KyberCoreServer
from tests.web.support import (
    ARTIFACTS,
    DOCS,
    FLEET_NAMES,
    expect_ready_tiles,
    open_fleet,
    start_print,
    tile,
    wait_until,
)

pytestmark = pytest.mark.browser


def temperature(page: Page, printer_id: str) -> float:
    text = tile(page, printer_id).locator(".temp .value").first.inner_text()
    return float(text.rstrip("°").replace(",", "."))


def test_the_overview_shows_the_fleet_live(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    open_fleet(page, kybercore_server.url)
    page.evaluate("window.__sameDocument = true")
    expect_ready_tiles(page)
    for printer_id, _name in FLEET_NAMES:
        card = tile(page, printer_id)
        expect(card.locator(".tag")).to_have_text(["test", printer_id])
        view = api.get(f"/api/printers/{printer_id}").json()
        assert abs(temperature(page, printer_id) - view["extruder"]["temperature"]) < 5
    expect(page.locator(".count-chip[data-group=ready] strong")).to_have_text("3")

    # Heat fleet-c through the API: its tile follows the real heater, without a reload.
    before = temperature(page, "fleet-c")
    answer = api.post("/api/printers/fleet-c/actions/set_temperature", json={"extruder": 60})
    assert answer.status_code == 200, answer.text
    hotend = tile(page, "fleet-c").locator(".temp").first
    expect(hotend.locator(".target")).to_have_text("/ 60°")
    expect(hotend).to_have_class(re.compile(r"\bheating\b"))
    seen: set[float] = set()

    def warmed() -> bool:
        seen.add(temperature(page, "fleet-c"))
        return max(seen) >= before + 15

    wait_until(warmed, timeout=20, what="the tile to show the hotend heating")
    # Several readings on the way up: the tile follows each update, not just the end state.
    assert len(seen - {before}) >= 2, f"readings seen on the tile: {sorted(seen)}"
    assert page.evaluate("window.__sameDocument") is True


def test_switching_language_changes_the_labels(
    new_page: Callable[..., Page], kybercore_server: KyberCoreServer
) -> None:
    page = new_page(locale="es-ES")
    open_fleet(page, kybercore_server.url)
    # The browser asks for Spanish: the page follows it.
    expect(page.locator("html")).to_have_attribute("lang", "es")
    expect(page.locator("#add-printer")).to_have_text("Añadir impresora")
    expect(tile(page, "fleet-a").locator(".pill")).to_have_text("Lista")
    expect(tile(page, "fleet-a").locator(".temp .label").first).to_have_text("Fusor")
    expect(page.locator("#search")).to_have_attribute("placeholder", re.compile("^Buscar"))
    pause = tile(page, "fleet-a").locator("[data-action=pause]")
    expect(pause).to_have_attribute("aria-label", "Pausar — Printer A")

    page.select_option("#lang", "en")
    expect(page.locator("html")).to_have_attribute("lang", "en")
    expect(page.locator("#add-printer")).to_have_text("Add printer")
    expect(tile(page, "fleet-a").locator(".pill")).to_have_text("Ready")
    expect(tile(page, "fleet-a").locator(".temp .label").first).to_have_text("Hotend")
    expect(pause).to_have_attribute("aria-label", "Pause — Printer A")
    expect(page.locator(".count-chip[data-group=ready]")).to_contain_text("ready")
    expect(page.locator("#filter-state option").first).to_have_text("All states")

    # Remembered: a reload keeps English although the browser prefers Spanish.
    page.reload()
    page.locator("#live[data-state=live]").wait_for()
    expect(page.locator("#add-printer")).to_have_text("Add printer")
    expect(page.locator("#lang")).to_have_value("en")

    # The theme follows the system (dark here), switches, and is remembered too.
    expect(page.locator("html")).to_have_attribute("data-theme", "dark")
    page.get_by_role("button", name="Switch to light theme").click()
    expect(page.locator("html")).to_have_attribute("data-theme", "light")
    page.reload()
    expect(page.locator("html")).to_have_attribute("data-theme", "light")
    expect(page.get_by_role("button", name="Switch to dark theme")).to_be_visible()

    # Every label exists in both languages (one file each): t() has no fallback to fetch.
    missing = page.evaluate(
        """async () => {
            const en = Object.keys((await import('/static/lang/en.js')).default);
            const es = Object.keys((await import('/static/lang/es.js')).default);
            return [...en.filter(k => !es.includes(k)), ...es.filter(k => !en.includes(k))];
        }"""
    )
    assert missing == []


def test_only_the_chosen_language_is_fetched(
    new_page: Callable[..., Page], kybercore_server: KyberCoreServer
) -> None:
    """Issue 19: one file per language, fetched on demand: Spanish only on the first switch."""
    page = new_page(locale="en-US")
    fetched: list[str] = []
    page.on("request", lambda r: fetched.append(r.url) if "/lang/" in r.url else None)
    open_fleet(page, kybercore_server.url)
    expect(page.locator("#add-printer")).to_have_text("Add printer")
    assert [url.rsplit("/", 1)[1] for url in fetched] == ["en.js"], fetched
    # Under the page's versioned prefix, like every other module.
    assert re.search(r"/static/v-[0-9a-f]+/lang/en\.js$", fetched[0]), fetched

    page.select_option("#lang", "es")
    expect(page.locator("#add-printer")).to_have_text("Añadir impresora")
    expect(tile(page, "fleet-a").locator(".pill")).to_have_text("Lista")
    assert [url.rsplit("/", 1)[1] for url in fetched] == ["en.js", "es.js"], fetched

    # Back and forth again: both are in memory, nothing more is fetched.
    page.select_option("#lang", "en")
    expect(page.locator("#add-printer")).to_have_text("Add printer")
    page.select_option("#lang", "es")
    expect(page.locator("#add-printer")).to_have_text("Añadir impresora")
    assert len(fetched) == 2, fetched

    # Remembered: the reload fetches Spanish only.
    fetched.clear()
    page.reload()
    page.locator("#live[data-state=live]").wait_for()
    expect(page.locator("#add-printer")).to_have_text("Añadir impresora")
    assert [url.rsplit("/", 1)[1] for url in fetched] == ["es.js"], fetched


def test_screenshots_of_the_overview(
    new_page: Callable[..., Page], kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    """A busy fleet (one printing, one paused, one heating) at desktop and phone widths."""
    start_print(api, "fleet-a", "bracket_v3_pla.gcode", moves=120)
    start_print(api, "fleet-b", "clip_petg.gcode", moves=120)
    assert api.post("/api/printers/fleet-b/actions/pause", json={}).status_code == 200
    api.post("/api/printers/fleet-c/actions/set_temperature", json={"extruder": 200, "bed": 60})
    wait_until(
        lambda: api.get("/api/printers/fleet-b").json()["job"]["state"] == "paused",
        what="fleet-b paused",
    )
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    shots = [
        ("overview-desktop-dark.png", 1440, 900, "dark"),
        ("overview-desktop-light.png", 1440, 900, "light"),
        ("overview-narrow-dark.png", 390, 844, "dark"),
        ("overview-narrow-light.png", 390, 844, "light"),
    ]
    for filename, width, height, scheme in shots:
        page = new_page(width=width, height=height, color_scheme=scheme)
        open_fleet(page, kybercore_server.url)
        expect(tile(page, "fleet-a").locator(".pill")).to_have_text("Printing")
        expect(tile(page, "fleet-b").locator(".pill")).to_have_text("Paused")
        expect(tile(page, "fleet-a").locator(".thumb img")).to_be_visible()
        # (Playwright's wait_for_function evaluates strings, which the page's CSP forbids.)
        wait_until(
            lambda page=page: page.evaluate(
                "[...document.querySelectorAll('.thumb img')].every(i => i.hidden || i.complete)"
            ),
            what="thumbnails loaded",
        )
        page.screenshot(path=str(ARTIFACTS / filename))
        assert (ARTIFACTS / filename).stat().st_size > 10_000
    # The README's picture: refreshed on demand only, so a test run leaves the tree clean.
    readme_picture = DOCS / "screenshot-overview.png"
    if not readme_picture.exists() or os.environ.get("KYBERCORE_UPDATE_SCREENSHOT") == "1":
        DOCS.mkdir(exist_ok=True)
        shutil.copyfile(ARTIFACTS / "overview-desktop-dark.png", readme_picture)
