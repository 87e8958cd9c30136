"""axe-core (pinned in package-lock.json) over every screen of the dashboard, in English and
Spanish, light and dark: no serious or critical violation.

A violation is reported with its rule, its impact, the screen and the first elements it
names, so a failure says what to fix without re-running anything."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, Final

import httpx
import pytest
from playwright.sync_api import Page

from tests.helpers import KyberCoreServer
from tests.web.support import open_fleet, start_print, tile

pytestmark = pytest.mark.browser

AXE: Final = Path(__file__).resolve().parents[2] / "node_modules" / "axe-core" / "axe.min.js"
TAGS: Final = ["wcag2a", "wcag2aa", "wcag21a", "wcag21aa", "wcag22aa", "best-practice"]
BLOCKING: Final = ("serious", "critical")


def _fleet_tiles(page: Page) -> None:
    page.locator("[data-mode=tiles]").click()


def _fleet_table(page: Page) -> None:
    page.locator("[data-mode=table]").click()
    page.locator("table").first.wait_for()


def _console(page: Page) -> None:
    tile(page, "fleet-a").locator("[data-action=console]").click()
    page.locator("#drawer:not([hidden])").wait_for()


def _printer_form(page: Page) -> None:
    page.locator("#add-printer").click()
    page.locator("dialog[open]").wait_for()


def _files(page: Page) -> None:
    tile(page, "fleet-a").locator("[data-action=files]").click()
    page.locator("#panel-files:not([hidden])").wait_for()


def _job_form(page: Page) -> None:
    _page("queue")(page)
    page.locator("#queue-add").click()
    page.locator("dialog[open]").wait_for()


def _page(name: str) -> Callable[[Page], None]:
    def show(page: Page) -> None:
        page.goto(page.url.split("#")[0] + f"#{name}")
        page.locator(f"#{name}-view:not([hidden])").wait_for()
        page.wait_for_load_state("networkidle")

    return show


SCREENS: Final[dict[str, Callable[[Page], None]]] = {
    "fleet-tiles": _fleet_tiles,
    "fleet-table": _fleet_table,
    "console": _console,
    "files": _files,
    "printer-form": _printer_form,
    "job-form": _job_form,
    "queue": _page("queue"),
    "history": _page("history"),
    "stats": _page("stats"),
}


def _violations(page: Page) -> list[dict[str, Any]]:
    # Evaluated through the DevTools protocol: the page's CSP (script-src 'self') stays on.
    page.evaluate(AXE.read_text())
    result = page.evaluate(
        "async (tags) => (await axe.run(document, {runOnly: {type: 'tag', values: tags}}))"
        ".violations.map(v => ({id: v.id, impact: v.impact, help: v.help,"
        " nodes: v.nodes.slice(0, 3).map(n => n.target.join(' ') + ' :: ' + n.failureSummary)}))",
        TAGS,
    )
    return [v for v in result if v["impact"] in BLOCKING]


@pytest.mark.parametrize("theme", ["light", "dark"])
@pytest.mark.parametrize("locale", ["en-US", "es-ES"])
def test_every_screen_has_no_serious_accessibility_violation(
    new_page: Callable[..., Page],
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    locale: str,
    theme: str,
) -> None:
    assert AXE.is_file(), f"{AXE} is missing: run `npm ci` (scripts/bootstrap.sh --test does)"
    # One printer printing: its pill, progress bar and times are on the screens too.
    start_print(api, "fleet-b", "a11y.gcode")
    found: dict[str, list[dict[str, Any]]] = {}
    for name, show in SCREENS.items():
        page = new_page(locale=locale, color_scheme=theme)
        open_fleet(page, kybercore_server.url)
        show(page)
        violations = _violations(page)
        if violations:
            found[name] = violations
    assert not found, json.dumps(found, indent=1, ensure_ascii=False)
