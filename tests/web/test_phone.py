"""The dashboard on a phone (390 px) and long file names anywhere: every control is a
44 px touch target, the header scrolls away, the bulk bar's icons tell its actions apart,
and a cut file name keeps its distinguishing end."""

from __future__ import annotations

from collections.abc import Callable

import httpx
import pytest
from playwright.sync_api import Locator, Page, expect

from tests.helpers import KyberCoreServer
from tests.web.support import ARTIFACTS, open_fleet, tile

pytestmark = pytest.mark.browser

LONG = "calibration_cube_10mm_four_walls_0.2mm_layers_petg.gcode"
TWIN = "calibration_cube_10mm_four_walls_0.2mm_layers_pla.gcode"


@pytest.fixture
def long_names(api: httpx.Client) -> None:
    """Two files on fleet-a whose names differ only at their ends."""
    for name in (LONG, TWIN):
        files = {"file": (name, b"G28\n", "application/octet-stream")}
        answer = api.post("/api/printers/fleet-a/files", files=files)
        assert answer.status_code == 201, answer.text


def _box(locator: Locator) -> dict[str, float]:
    box = locator.bounding_box()
    assert box is not None, locator
    return box


@pytest.mark.usefixtures("long_names")
def test_the_phone_layout_keeps_names_and_big_targets(
    new_page: Callable[..., Page], kybercore_server: KyberCoreServer
) -> None:
    page = new_page(width=390, height=844, color_scheme="light")
    open_fleet(page, kybercore_server.url)

    # Touch targets: the tile's buttons, the e-stop and the selection checkbox's row.
    card = tile(page, "fleet-a")
    for button in card.locator("button:visible").all():
        box = _box(button)
        assert min(box["height"], box["width"]) >= 44, (button.get_attribute("aria-label"), box)

    # The bulk bar: one icon per action, no two alike.
    page.get_by_role("checkbox", name="Select Printer A").check()
    bar = page.get_by_role("region", name="Bulk actions")
    icons = [b.locator("svg").inner_html() for b in bar.locator("button[data-bulk]").all()]
    assert len(icons) == len(set(icons)), "two bulk actions share an icon"
    for button in bar.locator("button[data-bulk]").all():
        assert _box(button)["height"] >= 44
    page.screenshot(path=str(ARTIFACTS / "phone-fleet.png"))
    bar.locator("[data-bulk=clear]").click()

    # The header scrolls away instead of covering a quarter of the screen.
    page.mouse.wheel(0, 600)
    expect(page.locator(".topbar")).not_to_be_in_viewport()

    # Files: the name column is there, wide enough to read, ending with what tells apart.
    page.mouse.wheel(0, -600)
    card.locator("[data-action=files]").click()
    row = page.locator(f'#panel-files tr[data-file="{LONG}"]')
    expect(row).to_be_visible()
    name = row.locator(".file-name")
    assert _box(name)["width"] >= 120
    expect(row.locator(".fn-tail")).to_be_visible()
    assert LONG.endswith(row.locator(".fn-tail").inner_text())
    tail = _box(row.locator(".fn-tail"))
    assert tail["x"] + tail["width"] <= _box(name)["x"] + _box(name)["width"] + 1
    expect(name).to_have_attribute("title", LONG)
    # Its buttons fit: Print and Delete, whole, inside the drawer.
    drawer = _box(page.locator("#drawer"))
    for button in row.locator("button").all():
        box = _box(button)
        assert box["x"] + box["width"] <= drawer["x"] + drawer["width"], box
        assert min(box["width"], box["height"]) >= 44, box
    page.screenshot(path=str(ARTIFACTS / "phone-files.png"))


@pytest.mark.usefixtures("long_names")
def test_a_cut_file_name_shows_its_end_on_the_desktop(
    page: Page, kybercore_server: KyberCoreServer
) -> None:
    open_fleet(page, kybercore_server.url)
    tile(page, "fleet-a").locator("[data-action=files]").click()
    for name, end in ((LONG, "petg.gcode"), (TWIN, "pla.gcode")):
        row = page.locator(f'#panel-files tr[data-file="{name}"]')
        expect(row.locator(".fn-tail")).to_contain_text(end)
        expect(row.locator(".fn-tail")).to_be_in_viewport()
