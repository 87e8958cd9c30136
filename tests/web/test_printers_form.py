"""Printers are added, edited and removed through the dashboard's forms."""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest
from playwright.sync_api import Page, expect

from kybercore.sim.stack import PrinterStack
from tests.helpers import KyberCoreServer
from tests.web.conftest import ConsoleErrors
from tests.web.support import open_fleet, tile

pytestmark = pytest.mark.browser

NEW_ID = "web-form"


@pytest.fixture
def forget_new_printer(api: httpx.Client) -> Iterator[None]:
    """Whatever happens in the test, printers.json ends without the added printer."""
    yield
    api.delete(f"/api/printers/{NEW_ID}")


@pytest.mark.usefixtures("forget_new_printer")
def test_a_printer_added_through_the_form_appears(
    page: Page,
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    fleet_stacks: list[PrinterStack],
    console_errors: ConsoleErrors,
) -> None:
    open_fleet(page, kybercore_server.url)
    page.get_by_role("button", name="Add printer").click()
    form = page.get_by_role("dialog", name="Add a printer")
    expect(form.get_by_label("Name")).to_be_focused()

    # Invalid input: the backend's 422 messages appear under the fields they are about.
    console_errors.expect(r"status of 422 .*/api/printers\]$")
    form.get_by_label("Moonraker URL").fill("ftp://printer.local")
    form.get_by_role("button", name="Add printer").click()
    url_error = form.locator("#pf-moonraker_url-error")
    expect(url_error).to_have_text("the URL must start with http:// or https://, not 'ftp:'")
    expect(form.locator("#pf-name-error")).to_be_visible()
    expect(form.get_by_label("Moonraker URL")).to_have_attribute("aria-invalid", "true")

    form.get_by_label("Name").fill("Web Form Printer")
    form.get_by_label("Id", exact=True).fill(NEW_ID)
    form.get_by_label("Moonraker URL").fill(fleet_stacks[2].url)
    form.get_by_label("Location").fill("Bench")
    form.get_by_label("Tags").fill("web, bench")
    form.get_by_role("button", name="Add printer").click()
    expect(form).to_be_hidden()

    card = tile(page, NEW_ID)
    expect(card.locator(".name")).to_have_text("Web Form Printer")
    expect(card.locator(".badge.conn")).to_have_text("Online", timeout=20_000)
    expect(card.locator(".badge.klippy")).to_have_text("Klipper ready")
    expect(card.locator(".tag")).to_have_text(["web", "bench"])
    stored = api.get(f"/api/printers/{NEW_ID}").json()
    assert stored["location"] == "Bench"
    assert stored["moonraker_url"] == fleet_stacks[2].url

    # A stored API key is never shown: the field stays empty and says so.
    secret = "kc-web-test-secret-key"
    assert api.patch(f"/api/printers/{NEW_ID}", json={"api_key": secret}).status_code == 200
    card.locator("[data-action=more]").click()
    page.get_by_role("menuitem", name="Edit printer").click()
    edit = page.get_by_role("dialog", name="Edit Web Form Printer")
    key = edit.get_by_role("textbox", name="API key")
    expect(key).to_have_value("")
    expect(key).to_have_attribute("placeholder", "set — leave empty to keep")
    assert secret not in page.content()

    # Edit: only what changed is sent; the key is kept.
    edit.get_by_label("Location").fill("Bench 2")
    edit.get_by_role("button", name="Save").click()
    expect(edit).to_be_hidden()
    expect(card.locator(".meta")).to_have_text("Bench 2")
    stored = api.get(f"/api/printers/{NEW_ID}").json()
    assert stored["location"] == "Bench 2"
    assert stored["api_key_set"] is True

    # Remove, through the edit dialog, after a confirmation.
    card.locator("[data-action=more]").click()
    page.get_by_role("menuitem", name="Edit printer").click()
    edit.get_by_role("button", name="Remove printer").click()
    confirm = page.get_by_role("dialog", name="Remove Web Form Printer?")
    confirm.get_by_role("button", name="Remove printer").click()
    expect(card).to_have_count(0)
    assert api.get(f"/api/printers/{NEW_ID}").status_code == 404
    expect(page.locator(".tile")).to_have_count(3)
