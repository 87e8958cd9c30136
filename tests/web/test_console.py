"""The console, the emergency stop and the fleet's toasts, in Chromium over real virtual
printers: Klipper's answers as Klipper gave them, a log that outlives tabs and the drawer,
one-click e-stop, and no toast for a print that ended while nobody watched."""

from __future__ import annotations

import re
import uuid

import httpx
import pytest
from playwright.sync_api import Locator, Page, expect

from kybercore.sim.stack import PrinterStack
from tests.helpers import KyberCoreServer, wait_until
from tests.web.conftest import ConsoleErrors
from tests.web.support import ARTIFACTS, open_fleet, start_print, tile

pytestmark = pytest.mark.browser


def open_console(page: Page, printer_id: str, name: str) -> tuple[Locator, Locator, Locator]:
    """Open a printer's console from its tile: (drawer, command box, log)."""
    tile(page, printer_id).locator("[data-action=console]").click()
    drawer = page.get_by_role("dialog", name=name)
    expect(drawer.get_by_role("tab", name="Console")).to_have_attribute("aria-selected", "true")
    log = drawer.get_by_role("log")
    expect(log).not_to_have_attribute("aria-busy", "true")  # its history has arrived
    return drawer, drawer.get_by_role("textbox", name="G-code command"), log


def send(command: Locator, script: str) -> None:
    command.fill(script)
    command.press("Enter")


def view(api: httpx.Client, printer_id: str) -> dict[str, object]:
    body: dict[str, object] = api.get(f"/api/printers/{printer_id}").json()
    return body


def test_an_unknown_command_is_red_with_klippers_words_and_m115_shows_the_firmware(
    page: Page, kybercore_server: KyberCoreServer
) -> None:
    open_fleet(page, kybercore_server.url)
    _, command, log = open_console(page, "fleet-a", "Printer A")
    live = log.locator(".line:not(.history)")

    send(command, "FOO_BAR")
    # Klipper 0.12 answers '// Unknown command:"FOO_BAR"' and Moonraker reports success:
    # shown as the error it is, in Klipper's words, and never as "done".
    expect(live.filter(has_text='Unknown command:"FOO_BAR"')).to_have_class(
        re.compile(r"\berror\b")
    )
    expect(live.filter(has_text="failed: FOO_BAR")).to_have_class(re.compile(r"\berror\b"))
    expect(live.filter(has_text='Unknown command:"FOO_BAR"')).to_have_count(1)  # not twice
    expect(log.locator(".line.ok")).to_have_count(0)

    send(command, "M115")
    expect(live.filter(has_text="FIRMWARE_NAME:Klipper")).to_have_class(re.compile(r"\bresponse\b"))
    expect(live.filter(has_text="FIRMWARE_NAME:Klipper")).to_have_count(1)
    expect(log.locator(".line.ok")).to_have_text([re.compile("done: M115")])

    # A "!!" line of a command that ran (Moonraker: success) is an error too.
    send(command, "RESPOND TYPE=error MSG=nozzle_clogged")
    expect(live.filter(has_text="!! nozzle_clogged")).to_have_class(re.compile(r"\berror\b"))
    expect(live.filter(has_text="failed: RESPOND")).to_be_visible()
    page.screenshot(path=str(ARTIFACTS / "console-klipper-errors.png"))


def test_the_log_survives_tabs_and_the_drawer_and_opens_with_the_printers_history(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    # Sent by another client before the page opens: the console starts with it.
    before = f"before-{uuid.uuid4().hex[:6]}"
    answer = api.post("/api/printers/fleet-b/gcode", json={"script": f"RESPOND MSG={before}"})
    assert answer.status_code == 200, answer.text
    open_fleet(page, kybercore_server.url)
    drawer, command, log = open_console(page, "fleet-b", "Printer B")
    expect(log.locator(".line.history.sent", has_text=f"> RESPOND MSG={before}")).to_have_count(1)
    expect(log.locator(".line.history.response", has_text=f"echo: {before}")).to_have_count(1)

    mine = f"mine-{uuid.uuid4().hex[:6]}"
    send(command, f"RESPOND MSG={mine}")
    expect(log.locator(".line.response", has_text=f"echo: {mine}")).to_have_count(1)
    expect(log.locator(".line.ok", has_text=f"done: RESPOND MSG={mine}")).to_have_count(1)
    count = log.locator(".line").count()

    # To the files and back: the same log.
    drawer.get_by_role("tab", name="Files").click()
    expect(drawer.get_by_role("log")).to_have_count(0)
    drawer.get_by_role("tab", name="Console").click()
    log = drawer.get_by_role("log")
    expect(log.locator(".line")).to_have_count(count)
    expect(log.locator(".line.ok", has_text=f"done: RESPOND MSG={mine}")).to_have_count(1)

    # Closed, a line arrives (another client's command), reopened: all of it is there.
    drawer.get_by_role("button", name="Close").click()
    expect(drawer).to_be_hidden()
    meanwhile = f"meanwhile-{uuid.uuid4().hex[:6]}"
    api.post("/api/printers/fleet-b/gcode", json={"script": f"RESPOND MSG={meanwhile}"})
    drawer, _, log = open_console(page, "fleet-b", "Printer B")
    expect(log.locator(".line.ok", has_text=f"done: RESPOND MSG={mine}")).to_have_count(1)
    expect(log.locator(".line.response", has_text=f"echo: {meanwhile}")).to_have_count(1)
    expect(log.locator(".line.history", has_text=f"echo: {before}")).to_have_count(1)

    # Another printer's console starts from that printer's history, not this log.
    drawer.get_by_role("button", name="Close").click()
    _, _, other = open_console(page, "fleet-c", "Printer C")
    expect(other.locator(".line", has_text=mine)).to_have_count(0)
    expect(other.locator(".line:not(.history)")).to_have_count(0)


def test_one_printers_emergency_stop_is_one_click(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    open_fleet(page, kybercore_server.url)
    card = tile(page, "fleet-c")
    try:
        card.locator("[data-action=emergency_stop]").click()
        # No question asked: Klipper is shut down at once.
        expect(card.locator(".pill")).to_have_text("Shutdown", timeout=20_000)
        expect(page.get_by_role("dialog")).to_have_count(0)
        assert view(api, "fleet-c")["klippy_state"] == "shutdown"
        expect(page.locator(".toast.ok", has_text="Emergency stop sent")).to_be_visible()
    finally:
        # The way back, so that the next tests find the printer ready.
        restart = api.post("/api/printers/fleet-c/actions/firmware_restart", json={})
        assert restart.status_code == 200, restart.text
        wait_until(
            lambda: view(api, "fleet-c")["klippy_state"] == "ready", timeout=60, what="ready"
        )
    expect(card.locator(".pill")).to_have_text("Ready", timeout=20_000)


def test_the_bulk_emergency_stop_still_asks(page: Page, kybercore_server: KyberCoreServer) -> None:
    open_fleet(page, kybercore_server.url)
    page.get_by_role("checkbox", name="Select Printer A").check()
    bar = page.get_by_role("region", name="Bulk actions")
    bar.locator("[data-bulk=emergency_stop]").click()
    preview = page.get_by_role("dialog", name="Emergency stop: 1 printer")
    expect(preview).to_be_visible()
    preview.get_by_role("button", name="Back").click()
    expect(preview).to_be_hidden()
    expect(tile(page, "fleet-a").locator(".pill")).to_have_text("Ready")


def test_focus_returns_to_the_more_button_after_its_dialog(
    page: Page, kybercore_server: KyberCoreServer
) -> None:
    open_fleet(page, kybercore_server.url)
    more = page.get_by_role("button", name="More actions — Printer B")
    more.click()
    page.get_by_role("menuitem", name="Set temperatures…").click()
    dialog = page.get_by_role("dialog", name="Temperatures — Printer B")
    expect(dialog).to_be_visible()
    page.keyboard.press("Escape")
    expect(dialog).to_be_hidden()
    expect(more).to_be_focused()

    # From the keyboard, with a confirmation this time.
    more.press("Enter")
    page.get_by_role("menuitem", name="Firmware restart").focus()
    page.keyboard.press("Enter")
    confirm = page.get_by_role("dialog", name="Firmware restart Printer B?")
    confirm.get_by_role("button", name="Back").click()
    expect(confirm).to_be_hidden()
    expect(more).to_be_focused()


def test_toasts_rise_above_the_bulk_bar(page: Page, kybercore_server: KyberCoreServer) -> None:
    open_fleet(page, kybercore_server.url)
    page.get_by_role("checkbox", name="Select Printer A").check()
    bar = page.get_by_role("region", name="Bulk actions")
    expect(bar).to_be_visible()
    page.get_by_role("button", name="More actions — Printer A").click()
    page.get_by_role("menuitem", name="Home all axes").click()
    toast = page.locator(".toast.ok", has_text="Homed.")
    expect(toast).to_be_visible(timeout=30_000)
    toast_box, bar_box = toast.bounding_box(), bar.bounding_box()
    assert toast_box is not None
    assert bar_box is not None
    assert toast_box["y"] + toast_box["height"] <= bar_box["y"], (toast_box, bar_box)
    page.screenshot(path=str(ARTIFACTS / "toast-above-bulk-bar.png"))

    # The bar goes: the toasts go back down to the corner.
    page.get_by_role("checkbox", name="Select Printer A").uncheck()
    expect(bar).to_be_hidden()
    expect(page.locator("#toasts")).to_have_attribute("style", re.compile(r"^(bottom: ;?)?$"))


def test_a_completed_printer_that_reconnects_shows_no_finished_toast(
    page: Page,
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    fleet_stacks: list[PrinterStack],
    console_errors: ConsoleErrors,
) -> None:
    open_fleet(page, kybercore_server.url)
    card = tile(page, "fleet-b")
    finished = page.locator(".toast", has_text="Print finished")
    # Seen finishing live: one toast (the control: the toast works).
    start_print(api, "fleet-b", "web_reconnect_done.gcode", moves=4)
    expect(card.locator(".pill")).to_have_text("Complete", timeout=60_000)
    expect(finished).to_have_count(1)
    finished.get_by_role("button", name="Dismiss").click()
    expect(finished).to_have_count(0)

    # Moonraker goes away and comes back; Klippy kept the finished job all along.
    stack = fleet_stacks[1]
    console = card.locator("[data-action=console]")
    expect(console).to_be_enabled()
    stack.stop_moonraker()
    try:
        expect(card.locator(".badge.conn")).to_have_text("Offline", timeout=15_000)
        # Nothing to type into while the printer is away.
        expect(console).to_be_disabled()
    finally:
        stack.start_moonraker()
    kybercore_server.wait_online(len(fleet_stacks), timeout=60)
    expect(card.locator(".badge.conn")).to_have_text("Online", timeout=30_000)
    expect(card.locator(".pill")).to_have_text("Complete", timeout=30_000)
    expect(console).to_be_enabled()
    # The toast would have come with the state that brought "Complete" back.
    page.evaluate("0")
    expect(finished).to_have_count(0)
