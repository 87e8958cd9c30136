"""A print watched on its tile, on a real virtual printer: "—" while it heats, a progress that
never goes back (the file's M73 steps notwithstanding), then the time left and the clock time
of the finish, in English and Spanish; sorting by time left puts it first."""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import httpx
import pytest
from playwright.sync_api import Page, expect

from tests.helpers import KyberCoreServer, wait_until
from tests.web.support import ARTIFACTS, FLEET, open_fleet

pytestmark = pytest.mark.browser

CUBE = Path(__file__).resolve().parents[1] / "samples/gcode/orcaslicer_cube_20mm_pla.gcode"
PRINTER = "fleet-b"
PRINT_TIMEOUT = 240.0
"""Heating takes ~10 s and the cube ~30 s; a busy machine may take several times longer."""

CLOCK = re.compile(r"(?P<h>\d{1,2}):(?P<m>\d{2})(?:\s?(?P<ampm>[AP]M))?")
"""A clock time as the browser's locale writes it: "15:42", or "3:42 PM" in en-US."""

READ_TILE = """(id) => {
    const tile = document.querySelector(`.tile[data-id="${id}"]`);
    const text = (sel) => tile.querySelector(sel)?.textContent ?? "";
    const temps = [...tile.querySelectorAll(".temp")].map((t) => [
        t.querySelector(".value").textContent, t.querySelector(".target").textContent]);
    return {
        pill: text(".pill"), pct: text(".pct"), eta: text(".eta"), done: text(".done"),
        etaTitle: tile.querySelector(".eta").getAttribute("title") ?? "",
        temps,
        order: [...document.querySelectorAll(".tile:not([hidden])")].map((t) => t.dataset.id),
    };
}"""


def slow_heating_cube() -> bytes:
    """The OrcaSlicer cube (a thumbnail header, M73 steps) with a hotter bed: heating lasts
    long enough to be watched."""
    return CUBE.read_bytes().replace(b"\nM190 S60 ", b"\nM190 S100 ")


@dataclass
class Reading:
    """One look at the tile."""

    pill: str
    pct: str
    eta: str
    done: str
    eta_title: str
    heating: bool
    order: list[str]

    @classmethod
    def of(cls, page: Page) -> Reading:
        raw: dict[str, Any] = page.evaluate(READ_TILE, PRINTER)
        return cls(
            raw["pill"],
            raw["pct"],
            raw["eta"],
            raw["done"],
            raw["etaTitle"],
            any(_below_target(value, target) for value, target in raw["temps"]),
            raw["order"],
        )

    @property
    def percent(self) -> int | None:
        match = re.fullmatch(r"(\d+) ?%", self.pct)
        return int(match[1]) if match else None


def _degrees(text: str) -> float | None:
    match = re.search(r"-?\d+(?:[.,]\d+)?", text)
    return float(match[0].replace(",", ".")) if match else None


def _below_target(value: str, target: str) -> bool:
    """A heater still on its way to its target (tile text: "62.3°", "/ 100°")."""
    now, wanted = _degrees(value), _degrees(target)
    return now is not None and wanted is not None and wanted > 0 and now < wanted - 10


@pytest.mark.timeout(600)  # a whole print, heating included: PRINT_TIMEOUT and the setup
def test_a_print_s_tile_shows_no_eta_while_heating_then_the_finish_clock(
    new_page: Callable[..., Page], kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    en = new_page()
    es = new_page(locale="es-ES")
    table = new_page()
    for page in (en, es, table):
        open_fleet(page, kybercore_server.url)
    en.select_option("#sort", "eta")
    table.click("[data-mode=table]")
    row_eta = table.locator(f'tr[data-id="{PRINTER}"] td.c-eta')
    answer = api.post(
        f"/api/printers/{PRINTER}/files",
        files={"file": ("web_progress_cube.gcode", slow_heating_cube(), "text/plain")},
        data={"start": "true", "confirm": "true"},
    )
    assert answer.status_code == 201, answer.text

    english: list[Reading] = []
    spanish: list[Reading] = []
    rows: list[str] = []
    finish_checked = False

    def watch() -> bool:
        nonlocal finish_checked
        english.append(Reading.of(en))
        spanish.append(Reading.of(es))
        rows.append(row_eta.inner_text())
        reading = english[-1]
        if not finish_checked and reading.done.startswith("done at"):
            _check_the_finish_clock(reading.done, api)
            # The header names the print that ends first: the only one running.
            expect(en.locator(".next-finish")).to_contain_text("Next: Printer B, done at")
            en.screenshot(path=str(ARTIFACTS / "progress-tile-done-at.png"))
            finish_checked = True
        return reading.pill == "Complete"

    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    wait_until(watch, timeout=PRINT_TIMEOUT, what=f"{PRINTER} to finish its print")

    printing = [r for r in english if r.pill in ("Printing", "Paused")]
    percents = [r.percent for r in english if r.percent is not None]
    assert percents == sorted(percents), f"progress went backwards: {percents}"
    assert percents[-1] == 100

    heating = [r for r in printing if r.heating]
    assert heating, "the heating was never seen on the tile"
    for reading in heating:
        assert (reading.eta, reading.done) == ("—", ""), reading
        assert reading.eta_title == "Time left: known once the printer starts extruding"
        # No time left yet: the printer sorts after the printers with one (here: by name).
        assert reading.order == list(FLEET)
        assert (reading.percent or 0) < 10, reading  # not the thumbnail header's 21 %

    timed = [r for r in printing if r.eta.endswith(" left")]
    assert timed, "the time left was never shown"
    for reading in timed:
        assert CLOCK.fullmatch(reading.done.removeprefix("done at ")), reading
        assert reading.order[0] == PRINTER, reading  # sorted by time left: first
    assert finish_checked

    # The table's "Left" column: the same, on one line.
    assert any(row == "—" for row, r in zip(rows, english, strict=True) if r in heating)
    assert any(re.fullmatch(r"\S.* left done at .+", row) for row in rows), rows

    es_printing = [r for r in spanish if r.pill in ("Imprimiendo", "En pausa")]
    assert any(r.eta == "—" for r in es_printing if r.heating)
    assert any(re.fullmatch(r"termina a las \d{2}:\d{2}", r.done) for r in es_printing)  # 24 h
    es_percents = [r.percent for r in spanish if r.percent is not None]
    assert es_percents == sorted(es_percents), f"progress went backwards: {es_percents}"


def _check_the_finish_clock(done: str, api: httpx.Client) -> None:
    """The tile's clock is the view's ``eta_at`` in local time (to the minute it may have
    turned since)."""
    eta_at = api.get(f"/api/printers/{PRINTER}").json()["job"]["eta_at"]
    assert isinstance(eta_at, int), eta_at
    assert eta_at > time.time() - 60
    match = CLOCK.fullmatch(done.removeprefix("done at "))
    assert match, done
    hours, minutes = int(match["h"]), int(match["m"])
    if match["ampm"]:
        hours = hours % 12 + (12 if match["ampm"] == "PM" else 0)
    expected = datetime.fromtimestamp(eta_at)
    apart = abs((hours * 60 + minutes) - (expected.hour * 60 + expected.minute)) % 1440
    assert min(apart, 1440 - apart) <= 2, (done, expected)
