"""Every screen of the dashboard, walked by axe-core (pinned in package-lock.json) in English
and Spanish, light and dark: no serious or critical violation, nor a missing main landmark
or a skipped heading level; and in Spanish, no English
word a Spanish user would meet.

A violation is reported with its rule, its impact, the screen and the first elements it
names, so a failure says what to fix without re-running anything."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from typing import Any, Final

import httpx
import pytest
from playwright.sync_api import Page, expect

from tests.helpers import KyberCoreServer
from tests.web.support import AXE, axe_violations, open_fleet, start_print, tile

pytestmark = pytest.mark.browser


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


def _bulk(page: Page) -> None:
    page.locator(".tile input.select").first.check()
    page.locator("#bulk:not([hidden])").wait_for()


def _printer_page(page: Page) -> None:
    tile(page, "fleet-b").locator(".name-link").click()  # the printing one
    page.locator("#printer-view:not([hidden]) .pp-macro").first.wait_for()
    page.wait_for_load_state("networkidle")


def _cameras(page: Page) -> None:
    page.goto(page.url.split("#")[0] + "#cameras")
    expect(page.locator(".cam-img[src]")).to_have_count(3)  # a picture on every tile


def _find_printers(page: Page) -> None:
    page.locator("#find-printers").click()
    expect(page.locator("dialog[open] .find-body .btn")).to_be_enabled()  # done listening


def _page(name: str) -> Callable[[Page], None]:
    def show(page: Page) -> None:
        page.goto(page.url.split("#")[0] + f"#{name}")
        page.locator(f"#{name}-view:not([hidden])").wait_for()
        page.wait_for_load_state("networkidle")

    return show


SCREENS: Final[dict[str, Callable[[Page], None]]] = {
    "fleet-tiles": _fleet_tiles,
    "fleet-table": _fleet_table,
    "bulk": _bulk,
    "console": _console,
    "files": _files,
    "printer-form": _printer_form,
    "job-form": _job_form,
    "queue": _page("queue"),
    "history": _page("history"),
    "stats": _page("stats"),
    "audit": _page("audit"),
    "notifications": _page("notifications"),
    "printer-page": _printer_page,
    "cameras": _cameras,
    "spools": _page("spools"),
    "find-printers": _find_printers,
}


WALK_TIMEOUT: Final = 600
"""Seconds one walk over every screen may take: ~60-100 s on an idle machine, several times
that on a shared, busy one (pytest's own 120 s default would kill the browser mid-walk)."""

THEMES: Final = ("light", "dark")


def _switch_theme(page: Page, theme: str) -> None:
    """The header's theme toggle, clicked from script: a modal dialog would block a pointer
    click, and what the toggle does to the page is the same either way."""
    if page.locator("html").get_attribute("data-theme") != theme:
        page.evaluate("document.getElementById('theme').click()")
    expect(page.locator("html")).to_have_attribute("data-theme", theme)


@pytest.mark.timeout(WALK_TIMEOUT)
@pytest.mark.parametrize("locale", ["en-US", "es-ES"])
def test_every_screen_has_no_serious_accessibility_violation(
    new_page: Callable[..., Page],
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    locale: str,
) -> None:
    assert AXE.is_file(), f"{AXE} is missing: run `npm ci` (scripts/bootstrap.sh --test does)"
    # One printer printing: its pill, progress bar and times are on the screens too.
    start_print(api, "fleet-b", "a11y.gcode")
    found: dict[str, list[dict[str, Any]]] = {}
    for name, show in SCREENS.items():
        # Each screen in a page of its own, opened in the system's light theme and then
        # switched to dark; closed before the next one opens, since open pages keep
        # rendering the live fleet and slow every later screen down.
        page = new_page(locale=locale, color_scheme="light")
        open_fleet(page, kybercore_server.url)
        show(page)
        for theme in THEMES:
            _switch_theme(page, theme)
            violations = axe_violations(page)
            if violations:
                found[f"{name} ({theme})"] = violations
        page.context.close()
    assert not found, json.dumps(found, indent=1, ensure_ascii=False)


ENGLISH: Final = frozenset(
    """
    the and of to with from your printer printers ready printing paused queue history
    statistics settings file files upload cancel pause resume start stop select selected
    none all add remove delete save close back next done left time job jobs temperature
    bed hotend nozzle layer search state tag tags location sort name tiles table light
    dark language connected disconnected online offline emergency restart print
    prints finished complete cancelled failed waiting clear plate hold release
    notifications channel send yes loading unknown show hide more less today week hours
    minutes seconds copies attempts refresh drop choose click here filter
    """.split()  # noqa: SIM905 -- a word list reads best as words
)
"""Words that give an untranslated English string away (none of them is Spanish)."""

# Skipped: what the user named (printers, files, tags) and wrote (macros and their
# descriptions come from the printer's own Klipper configuration).
_WORDS = """() => {
  const skip = "script, style, .name, .meta, .tag, .file-name, .c-file, .console-log, code, "
    + ".mono, .pp-macro";
  const texts = [];
  const walker = document.createTreeWalker(document.body, NodeFilter.SHOW_TEXT);
  while (walker.nextNode()) {
    const el = walker.currentNode.parentElement;
    if (!el || el.closest(skip) || !el.checkVisibility()) continue;
    texts.push(walker.currentNode.textContent);
  }
  for (const el of document.querySelectorAll("[aria-label], [title], [placeholder]")) {
    if (!el.checkVisibility() || el.closest(skip)) continue;
    for (const attr of ["aria-label", "title", "placeholder"]) {
      texts.push(el.getAttribute(attr) || "");
    }
  }
  return texts.join(" | ");
}"""


@pytest.mark.timeout(WALK_TIMEOUT)
def test_every_screen_speaks_spanish(
    new_page: Callable[..., Page], kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    # What the printers and files are called is the user's, not the interface's.
    data = ["KyberCore", "Klipper", "Moonraker"]
    for p in api.get("/api/printers").json():
        data += [p["name"], p["id"], p["model"], p["location"], *p["tags"]]
    found: dict[str, list[str]] = {}
    for name, show in SCREENS.items():
        # Opened in English and switched: what was built before the switch must follow.
        page = new_page(locale="en-US", color_scheme="light")
        open_fleet(page, kybercore_server.url)
        page.select_option("#lang", "es")
        # The switch applies once es.json has loaded; a dialog opened before that is built in
        # English (a user cannot switch with a dialog open: it is modal).
        expect(page.locator("html")).to_have_attribute("lang", "es")
        show(page)
        text = re.sub(r"\S+\.(gcode|gco|g)\b", " ", page.evaluate(_WORDS))  # the user's files
        for value in sorted(filter(None, data), key=len, reverse=True):
            text = text.replace(value, " ")
        # Ids of printers no longer in the fleet (statistics remember them): "from-cli".
        text = re.sub(r"\b\w+(?:[-_]\w+)+\b", " ", text)
        words = {w for w in re.findall(r"[A-Za-z]+", text) if w.lower() in ENGLISH}
        if words:
            parts = [part.strip() for part in text.split(" | ")]
            english = [part for part in parts if set(re.findall("[A-Za-z]+", part)) & words]
            found[name] = sorted(words) + english
        page.context.close()
    assert not found, json.dumps(found, indent=1, ensure_ascii=False)
