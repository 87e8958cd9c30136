"""Actions from the dashboard reach the real printers, and refusals show the backend's words."""

from __future__ import annotations

import json
import re

import httpx
import pytest
from playwright.sync_api import Page, Request, expect

from tests.helpers import KyberCoreServer
from tests.web.conftest import ConsoleErrors
from tests.web.support import ARTIFACTS, open_fleet, start_print, tile

pytestmark = pytest.mark.browser


def job_state(api: httpx.Client, printer_id: str) -> str:
    state: str = api.get(f"/api/printers/{printer_id}").json()["job"]["state"]
    return state


def test_pausing_from_the_ui_pauses_the_real_printer(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    open_fleet(page, kybercore_server.url)
    page.evaluate("window.__sameDocument = true")
    card = tile(page, "fleet-a")
    pause, resume, cancel = (
        card.locator(f"[data-action={a}]") for a in ("pause", "resume", "cancel")
    )
    # Idle: nothing to pause, resume or cancel.
    for button in (pause, resume, cancel):
        expect(button).to_be_disabled()

    start_print(api, "fleet-a", "web_pause_test.gcode")
    expect(card.locator(".pill")).to_have_text("Printing")
    expect(card.locator(".file")).to_have_text("web_pause_test.gcode")
    expect(card.locator(".thumb img")).to_be_visible()
    expect(pause).to_be_enabled()
    expect(resume).to_be_disabled()
    expect(pause).to_have_attribute("aria-label", "Pause — Printer A")

    pause.click()
    expect(card.locator(".pill")).to_have_text("Paused", timeout=20_000)
    assert job_state(api, "fleet-a") == "paused"
    expect(page.locator(".toast.ok", has_text="Print paused.")).to_be_visible()
    expect(resume).to_be_enabled()
    expect(pause).to_be_disabled()

    # Cancel asks first, in a modal driven from the keyboard: the safe choice has the focus,
    # Escape backs out, focus returns to the button, and the print is left alone.
    cancel.focus()
    page.keyboard.press("Enter")
    dialog = page.get_by_role("dialog", name="Cancel the print on Printer A?")
    expect(dialog).to_be_visible()
    expect(dialog.get_by_role("button", name="Back")).to_be_focused()
    page.keyboard.press("Escape")
    expect(dialog).to_be_hidden()
    expect(cancel).to_be_focused()
    assert job_state(api, "fleet-a") == "paused"

    cancel.click()
    dialog.get_by_role("button", name="Cancel print").click()
    expect(card.locator(".pill")).to_have_text("Cancelled", timeout=20_000)
    assert job_state(api, "fleet-a") == "cancelled"
    expect(cancel).to_be_disabled()
    assert page.evaluate("window.__sameDocument") is True


def test_an_invalid_action_shows_the_backends_error(
    page: Page,
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    console_errors: ConsoleErrors,
) -> None:
    # What the backend says when asked to pause an idle printer.
    refusal = api.post("/api/printers/fleet-b/actions/pause", json={})
    assert refusal.status_code == 409
    reason = refusal.json()["error"]["reasons"][0]

    open_fleet(page, kybercore_server.url)
    page.get_by_role("checkbox", name="Select Printer B").check()
    bar = page.get_by_role("region", name="Bulk actions")
    expect(bar.locator(".bulk-count")).to_have_text("1 selected")
    bar.locator("[data-bulk=pause]").click()

    # The dry run already says it will refuse, and why.
    preview = page.get_by_role("dialog", name="Pause: 1 printer")
    expect(preview.locator("[data-printer=fleet-b]")).to_contain_text("will refuse")
    expect(preview.locator("[data-printer=fleet-b]")).to_contain_text(reason["en"])
    # Every selected printer refuses: nothing to run, and the dialog says so.
    expect(preview).to_contain_text("The printer cannot do this now")
    expect(preview.get_by_role("button", name=re.compile("^Pause on"))).to_have_count(0)
    preview.get_by_role("button", name="Back").click()
    expect(preview).to_be_hidden()
    assert job_state(api, "fleet-b") not in ("printing", "paused")

    # In Spanish, the console shows the backend's Spanish reason for a refused G-code.
    page.select_option("#lang", "es")
    m112 = api.post("/api/printers/fleet-c/gcode", json={"script": "M112"})
    assert m112.status_code == 422
    spanish = m112.json()["error"]["reasons"][0]["es"]
    console_errors.expect(r"status of 422 .*/api/printers/fleet-c/gcode")
    tile(page, "fleet-c").locator("[data-action=console]").click()
    drawer = page.get_by_role("dialog", name="Printer C")
    expect(drawer.get_by_role("tab", name="Consola")).to_have_attribute("aria-selected", "true")
    command = drawer.get_by_role("textbox", name="Comando G-code")
    command.fill("M112")
    command.press("Enter")
    log = drawer.get_by_role("log")
    # (Lines marked "history" are the printer's console from before the page opened.)
    expect(log.locator(".line.error:not(.history)")).to_have_text(re.compile(re.escape(spanish)))
    # A harmless command: sent, answered with Klipper's response.
    command.fill("M115")
    command.press("Enter")
    expect(log.locator(".line.response:not(.history)", has_text="FIRMWARE_NAME")).to_be_visible()
    expect(log.locator(".line.ok")).to_have_text(re.compile("hecho: M115"))


def test_a_console_command_needing_confirmation_shows_why_and_is_resent_only_if_confirmed(
    page: Page,
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    console_errors: ConsoleErrors,
) -> None:
    # X 1000 is beyond fleet-a's 220 mm: the backend answers 409 confirmation_required with
    # the reason, before anything reaches the printer.
    script = "G1 X1000"
    answer = api.post("/api/printers/fleet-a/gcode", json={"script": script})
    assert answer.status_code == 409, answer.text
    error = answer.json()["error"]
    assert error["code"] == "confirmation_required"
    assert [r["code"] for r in error["reasons"]] == ["gcode_move_outside_volume"]
    reason = error["reasons"][0]

    sent: list[Request] = []
    page.on("request", lambda r: sent.append(r) if r.url.endswith("/fleet-a/gcode") else None)
    console_errors.expect(r"status of 409 .*/api/printers/fleet-a/gcode\]$")
    open_fleet(page, kybercore_server.url)
    tile(page, "fleet-a").locator("[data-action=console]").click()
    drawer = page.get_by_role("dialog", name="Printer A")
    command = drawer.get_by_role("textbox", name="G-code command")
    log = drawer.get_by_role("log")

    # Backed out of: nothing is sent again, the log says so.
    command.fill(script)
    command.press("Enter")
    warnings = page.get_by_role("dialog", name="Warnings for Printer A")
    expect(warnings.locator(".reason")).to_have_text([reason["en"]])
    expect(warnings.get_by_role("button", name="Back")).to_be_focused()
    page.screenshot(path=str(ARTIFACTS / "console-confirm-warnings.png"))
    warnings.get_by_role("button", name="Back").click()
    expect(warnings).to_be_hidden()
    expect(log.locator(".line.error:not(.history)")).to_have_text(
        [re.compile("Not sent: the warnings were not confirmed.")]
    )
    expect(command).to_be_focused()
    assert [json.loads(r.post_data or "{}") for r in sent] == [{"script": script, "confirm": False}]

    # Confirmed: sent once more, with confirm. Klipper itself refuses the move (unhomed or
    # out of range) and the console shows its answer; the printer stays idle.
    console_errors.expect(r"status of \d+ .*/api/printers/fleet-a/gcode\]$")
    command.fill(script)
    command.press("Enter")
    warnings.get_by_role("button", name="Go ahead").click()
    klipper = re.compile(
        r"Klipper refused (it|the values): (Must home axis first|Move out of range)"
    )
    expect(log.locator(".line.error", has_text=klipper)).to_have_count(1)
    assert [json.loads(r.post_data or "{}") for r in sent][1:] == [
        {"script": script, "confirm": False},
        {"script": script, "confirm": True},
    ]
    assert job_state(api, "fleet-a") not in ("printing", "paused")

    # In Spanish, the dialog shows the backend's Spanish reason.
    page.select_option("#lang", "es")
    command = drawer.get_by_role("textbox", name="Comando G-code")
    command.fill(script)
    command.press("Enter")
    avisos = page.get_by_role("dialog", name="Avisos para Printer A")
    expect(avisos.locator(".reason")).to_have_text([reason["es"]])
    avisos.get_by_role("button", name="Volver").click()
    assert len(sent) == 4
