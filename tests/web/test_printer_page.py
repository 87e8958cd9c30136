"""The printer page (#printer/<id>) in Chromium over real virtual printers: reached from a
tile and left with the back button; homing, jogging, a hotend target and a macro reach
Klipper; the print card follows a print and pauses, resumes and cancels it; after an
e-stop one click brings Klippy back; Spanish, and a phone."""

from __future__ import annotations

import re
from collections.abc import Callable

import httpx
import pytest
from playwright.sync_api import Locator, Page, expect

from tests.helpers import KyberCoreServer, objects_gcode, wait_until
from tests.web.support import ARTIFACTS, axe_violations, make_idle, open_fleet, start_print, tile

pytestmark = pytest.mark.browser


def view(api: httpx.Client, printer_id: str) -> dict[str, object]:
    body: dict[str, object] = api.get(f"/api/printers/{printer_id}").json()
    return body


def position(api: httpx.Client, printer_id: str) -> list[float]:
    toolhead = view(api, printer_id)["toolhead"]
    assert isinstance(toolhead, dict)
    return list(toolhead["position"] or [])


def settled_x(api: httpx.Client, printer_id: str) -> float:
    """X once the moves queued so far are done (M400) and the view shows where Klipper
    says the toolhead is (M114): homing may still be moving it when "Homed" shows."""
    answer = api.post(f"/api/printers/{printer_id}/gcode", json={"script": "M400\nM114"})
    assert answer.status_code == 200, answer.text
    found = re.search(r"X:(-?[0-9.]+)", " ".join(answer.json()["response"]))
    assert found, answer.text
    x = float(found.group(1))
    wait_until(lambda: abs(position(api, printer_id)[0] - x) < 0.01, what=f"the view at X {x}")
    return x


def shown_x(section: Locator) -> float:
    """The X the printer page shows, as a number (nan while it shows none)."""
    found = re.search(r"X (-?[0-9.]+)", section.locator(".pp-position").inner_text())
    return float(found.group(1)) if found else float("nan")


def open_page(page: Page, url: str, printer_id: str, name: str) -> Locator:
    """Open the printer's page from its tile; returns the page's section."""
    open_fleet(page, url)
    tile(page, printer_id).get_by_role("link", name=name).click()
    section = page.locator("#printer-view")
    expect(section.get_by_role("heading", level=1, name=name)).to_be_visible()
    return section


def test_a_tile_opens_the_page_and_back_returns_to_the_fleet(
    page: Page, kybercore_server: KyberCoreServer
) -> None:
    section = open_page(page, kybercore_server.url, "fleet-a", "Printer A")
    assert page.url.endswith("#printer/fleet-a")
    expect(page.locator("#fleet")).to_be_hidden()
    expect(section.locator("#pp-temps .pp-graph[data-points]")).to_be_attached()
    expect(section.get_by_role("log")).to_be_visible()  # the console
    expect(section.locator("#pp-files-card th", has_text="Material")).to_be_visible()
    page.go_back()
    expect(page.locator(".tile")).to_have_count(3)
    expect(section).to_be_hidden()
    page.go_forward()  # linkable: the address alone opens it
    expect(section.get_by_role("heading", level=1, name="Printer A")).to_be_visible()
    page.reload()
    expect(section.get_by_role("heading", level=1, name="Printer A")).to_be_visible()


def test_home_jog_target_and_a_macro_reach_klipper(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    # Klipper forgets homing only on a restart: start from unhomed to see the guard.
    api.post("/api/printers/fleet-a/gcode", json={"script": "M84"})
    wait_until(lambda: view(api, "fleet-a")["toolhead"]["homed_axes"] == "", what="unhomed")  # type: ignore[index]
    section = open_page(page, kybercore_server.url, "fleet-a", "Printer A")
    jog = section.get_by_role("button", name="X+")
    expect(jog).to_be_disabled()
    expect(section.locator("#pp-toolhead .pp-hint")).to_have_text("Home X Y Z before moving it.")
    extrude = section.get_by_role("button", name="Extrude")
    expect(extrude).to_be_disabled()  # cold hotend: Klipper's min_extrude_temp
    expect(section.locator("#pp-extruder .pp-hint")).to_contain_text("min_extrude_temp")

    section.get_by_role("button", name="Home all").click()
    # G28 homes X, then Y, then Z: X's jog comes alive before the others are homed.
    expect(section.locator(".pp-homed")).to_have_text("Homed: X Y Z", timeout=60_000)
    expect(jog).to_be_enabled()
    start_x = settled_x(api, "fleet-a")
    # Seen once on a loaded CI machine: after G28 Klipper put X at -262.7, outside the
    # axis (0-220), from where KyberCore rightly refuses the jog. The virtual MCU's endstop
    # fired late against the homing move; homing X again gives the real printer's 0.
    for _ in range(3):
        if 0 <= start_x <= 200:
            break
        assert api.post("/api/printers/fleet-a/gcode", json={"script": "G28 X"}).status_code == 200
        start_x = settled_x(api, "fleet-a")
    assert 0 <= start_x <= 200, start_x
    section.get_by_role("radiogroup", name="Step (mm)").get_by_text("10", exact=True).click()
    jog.click()
    wait_until(
        lambda: abs(position(api, "fleet-a")[0] - (start_x + 10)) < 0.01,
        timeout=60,
        what=f"X {start_x:.2f} + 10",
    )
    # Compared as numbers: M114 gives 3 decimals, and Python and the page may round a
    # final 5 (X 19.325) differently to the 2 decimals shown.
    wait_until(
        lambda: abs(shown_x(section) - (start_x + 10)) <= 0.0051,
        what=f"the page showing X {start_x + 10:.3f}",
    )

    target = section.get_by_role("spinbutton", name="New target for Hotend, °C")
    target.fill("45")
    target.press("Enter")
    wait_until(lambda: view(api, "fleet-a")["extruder"]["target"] == 45, what="target 45")  # type: ignore[index]
    expect(section.locator('tr[data-heater="extruder"] .pp-target')).to_contain_text("45")

    macros = section.locator(".pp-macros")
    expect(macros.get_by_role("button", name="PARK")).to_be_visible()
    expect(macros.locator("button", has_text=re.compile("^_"))).to_have_count(0)
    macros.get_by_role("button", name="PARK").click()
    wait_until(lambda: position(api, "fleet-a")[:2] == [215.0, 215.0], what="parked")
    expect(section.get_by_role("log")).to_contain_text("PARK")


def test_the_print_card_follows_a_print_and_pauses_resumes_and_cancels_it(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    """Mainsail's status panel: the file, its progress and time, and the print's buttons
    (the same validated actions as the tiles; cancel asks first)."""
    make_idle(kybercore_server, api)
    section = open_page(page, kybercore_server.url, "fleet-b", "Printer B")
    card = section.locator("#pp-job")
    pause, resume, cancel = (
        card.get_by_role("button", name=f"{label} — Printer B")
        for label in ("Pause", "Resume", "Cancel print")
    )
    expect(card.locator(".pp-job-file")).to_have_text("No job")
    for button in (pause, resume, cancel):
        expect(button).to_be_disabled()

    start_print(api, "fleet-b", "web_page_print.gcode")
    expect(card.locator(".pp-job-file")).to_have_text("web_page_print.gcode")
    expect(card.locator(".pp-job-thumb")).to_be_visible()
    expect(card.locator(".pct")).to_have_text(re.compile(r"^\d+(\.\d)?\s?%$"))
    # (No print time: Klipper counts it from the first extrusion, and this file travels.)
    pause.click()
    wait_until(lambda: view(api, "fleet-b")["job"]["state"] == "paused", what="paused")  # type: ignore[index]
    expect(resume).to_be_enabled()
    expect(pause).to_be_disabled()
    resume.click()
    wait_until(lambda: view(api, "fleet-b")["job"]["state"] == "printing", what="printing")  # type: ignore[index]
    cancel.click()
    page.get_by_role("dialog", name="Cancel the print on Printer B?").get_by_role(
        "button", name="Cancel print"
    ).click()
    wait_until(lambda: view(api, "fleet-b")["job"]["state"] == "cancelled", what="cancelled")  # type: ignore[index]
    expect(cancel).to_be_disabled()


def test_an_object_of_the_print_is_excluded_from_the_page_after_a_confirmation(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    """Mainsail's "exclude object": the print's labelled objects on a map of the bed and
    in a list; excluding one asks first, then Klipper skips it."""
    make_idle(kybercore_server, api)
    upload = api.post(
        "/api/printers/fleet-b/files",
        files={"file": ("two_parts.gcode", objects_gcode(80), "application/octet-stream")},
        data={"start": "true", "confirm": "true"},
    )
    assert upload.json()["started"] is True, upload.text
    try:
        section = open_page(page, kybercore_server.url, "fleet-b", "Printer B")
        objects = section.locator("#pp-objects")
        expect(objects.get_by_role("heading", name="Objects")).to_be_visible()
        rows = objects.locator(".pp-objects-list li")
        expect(rows.locator(".pp-object-name")).to_have_text(["PART_A", "PART_B"])
        expect(objects.get_by_role("img", name="The bed with the print's objects")).to_be_visible()
        expect(objects.locator(".pp-objects-map polygon")).to_have_count(2)
        expect(objects.locator(".is-current")).to_have_count(1, timeout=15_000)

        # Read again every few seconds as the object printing changes; a keyboard user's
        # focus stays on its button meanwhile.
        exclude = objects.get_by_role("button", name="Exclude PART_B")
        exclude.focus()
        for _ in range(2):
            with page.expect_response(re.compile(r"/api/printers/fleet-b/objects$")):
                pass
        expect(exclude).to_be_focused()
        exclude.click()
        dialog = page.get_by_role("dialog", name="Exclude PART_B from the print on Printer B?")
        dialog.get_by_role("button", name="Back").click()
        expect(dialog).to_be_hidden()
        assert api.get("/api/printers/fleet-b/objects").json()["excluded"] == []
        exclude.click()
        dialog.get_by_role("button", name="Exclude object").click()
        expect(page.locator(".toast.ok", has_text="PART_B excluded")).to_be_visible()
        assert api.get("/api/printers/fleet-b/objects").json()["excluded"] == ["PART_B"]
        part_b = objects.locator('li[data-object="PART_B"]')
        expect(part_b.locator(".pp-object-state")).to_have_text("Excluded", timeout=15_000)
        expect(exclude).to_be_disabled()
        expect(objects.locator(".pp-objects-map polygon.excluded")).to_have_count(1)
        objects.screenshot(path=str(ARTIFACTS / "printer-page-objects.png"))
        assert axe_violations(page) == []  # as every screen in test_accessibility

        page.locator("#lang").select_option("es")
        expect(objects.get_by_role("heading", name="Objetos")).to_be_visible()
        expect(part_b.locator(".pp-object-state")).to_have_text("Excluido")
        page.locator("#lang").select_option("en")
    finally:
        api.post("/api/printers/fleet-b/actions/cancel", json={})
    wait_until(lambda: view(api, "fleet-b")["job"]["state"] == "cancelled", what="cancelled")  # type: ignore[index]
    expect(section.locator("#pp-objects")).to_be_hidden()


def test_after_an_estop_one_click_restarts_the_firmware(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    section = open_page(page, kybercore_server.url, "fleet-c", "Printer C")
    restart = section.get_by_role("button", name="Firmware restart")
    expect(restart).to_be_hidden()
    section.get_by_role("button", name="Emergency stop").click()  # one click, no dialog
    expect(restart).to_be_visible(timeout=30_000)
    assert view(api, "fleet-c")["klippy_state"] == "shutdown"
    try:
        expect(section.locator("#pp-toolhead .pp-hint")).to_have_text(
            "The printer is not ready: nothing can move."
        )
        restart.click()
    finally:  # the next tests need the printer ready, whatever this one found
        if view(api, "fleet-c")["klippy_state"] == "shutdown":
            api.post("/api/printers/fleet-c/actions/firmware_restart", json={})
    wait_until(lambda: view(api, "fleet-c")["klippy_state"] == "ready", timeout=60, what="ready")
    expect(restart).to_be_hidden()


def test_the_page_in_spanish_and_on_a_phone(
    new_page: Callable[..., Page], kybercore_server: KyberCoreServer
) -> None:
    wide = new_page(locale="es-ES", color_scheme="light")
    section = open_page(wide, kybercore_server.url, "fleet-b", "Printer B")
    expect(section.get_by_role("heading", name="Cabezal")).to_be_visible()
    expect(section.get_by_role("button", name="Origen de todos")).to_be_visible()
    expect(section.get_by_role("link", name="Todas las impresoras")).to_be_visible()
    expect(section.get_by_role("button", name="PARK")).to_be_visible()  # macros loaded
    # No stray "null" where the header has nothing to say (no print to finish).
    expect(wide.locator("#counts")).not_to_contain_text("null")
    webcam = section.locator("#printer-webcam img")
    wait_until(lambda: webcam.evaluate("i => i.naturalWidth") > 0, what="the webcam's picture")
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    wide.screenshot(path=str(ARTIFACTS / "printer_page.png"), full_page=True)

    phone = new_page(width=390, height=844)
    section = open_page(phone, kybercore_server.url, "fleet-b", "Printer B")
    for name in ("Home all", "X+", "Extrude"):
        box = section.get_by_role("button", name=name).bounding_box()
        assert box is not None, name
        assert box["height"] >= 44, (name, box)
    width = phone.evaluate("document.documentElement.scrollWidth")
    assert width <= 390, f"the page scrolls sideways: {width} px"
    phone.screenshot(path=str(ARTIFACTS / "printer_page_phone.png"), full_page=True)
