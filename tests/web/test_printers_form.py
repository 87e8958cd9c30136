"""Printers are added, edited and removed through the dashboard's forms."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import httpx
import pytest
from playwright.sync_api import Page, expect

from kybercore.sim.stack import PrinterStack, free_port
from tests.helpers import KyberCoreServer
from tests.web.conftest import ConsoleErrors
from tests.web.support import ARTIFACTS, open_fleet, tile

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
    printer: PrinterStack,
    console_errors: ConsoleErrors,
) -> None:
    """A printer not yet in the fleet (``printer``: one Moonraker drives one printer)."""
    open_fleet(page, kybercore_server.url)
    page.get_by_role("button", name="Add printer").click()
    form = page.get_by_role("dialog", name="Add a printer")
    expect(form.get_by_label("Name")).to_be_focused()

    # Invalid input: the backend's 422 messages appear under the fields they are about.
    console_errors.expect(r"status of 422 .*/api/printers(\?check=true)?\]$")
    form.get_by_label("Moonraker URL").fill("ftp://printer.local")
    form.get_by_role("button", name="Add printer").click()
    url_error = form.locator("#pf-moonraker_url-error")
    expect(url_error).to_have_text("the URL must start with http:// or https://, not 'ftp:'")
    expect(form.locator("#pf-name-error")).to_be_visible()
    expect(form.get_by_label("Moonraker URL")).to_have_attribute("aria-invalid", "true")

    form.get_by_label("Name").fill("Web Form Printer")
    form.get_by_label("Id", exact=True).fill(NEW_ID)
    # As people type it, without http://: completed, then tested before it is saved.
    form.get_by_label("Moonraker URL").fill(printer.url.removeprefix("http://"))
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
    assert stored["moonraker_url"] == printer.url

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

    # Edit: only what changed is sent; the key is kept (a site matters only on NATS).
    edit.get_by_label("Location").fill("Bench 2")
    edit.get_by_label("Site", exact=True).fill("lab-b")
    edit.get_by_role("button", name="Save").click()
    expect(edit).to_be_hidden()
    expect(card.locator(".meta")).to_have_text("Bench 2")
    stored = api.get(f"/api/printers/{NEW_ID}").json()
    assert stored["location"] == "Bench 2"
    assert stored["site"] == "lab-b"
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


def test_the_backends_field_problems_appear_under_their_fields_in_spanish(
    new_page: Callable[..., Page],
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    fleet_stacks: list[PrinterStack],
    request: pytest.FixtureRequest,
) -> None:
    # What the form sends for these inputs, and the backend's per-field answer to it.
    body = {
        "name": "",
        "moonraker_url": "ftp://printer.local",
        "model": "",
        "location": "",
        "tags": [],
        "notes": "",
        "enabled": True,
        "capabilities": {"nozzle_diameter": -1},
    }
    answer = api.post("/api/printers", json=body)
    assert answer.status_code == 422, answer.text
    fields = {f["field"]: f["es"] for f in answer.json()["error"]["fields"]}
    assert set(fields) == {"name", "moonraker_url", "capabilities.nozzle_diameter"}

    page = new_page(locale="es-ES")
    console_errors: ConsoleErrors = request.node.console_errors  # this page's
    open_fleet(page, kybercore_server.url)
    page.get_by_role("button", name="Añadir impresora").click()
    form = page.get_by_role("dialog", name="Añadir una impresora")
    console_errors.expect(r"status of 422 .*/api/printers(\?check=true)?\]$")
    form.get_by_label("URL de Moonraker").fill("ftp://printer.local")
    capabilities = form.locator("details.caps")
    capabilities.locator("summary").click()
    form.get_by_label("Boquilla (mm)").fill("-1")
    capabilities.locator("summary").click()  # closed again: the error must open it
    form.get_by_role("button", name="Añadir impresora").click()

    url_error = form.locator("#pf-moonraker_url-error")
    expect(url_error).to_have_text(fields["moonraker_url"])
    expect(url_error).to_have_text("la URL debe empezar por http:// o https://, no por 'ftp:'")
    expect(form.locator("#pf-name-error")).to_have_text(fields["name"])
    nozzle_error = form.locator('[id="pf-capabilities.nozzle_diameter-error"]')
    expect(nozzle_error).to_have_text(fields["capabilities.nozzle_diameter"])
    expect(nozzle_error).to_be_visible()
    expect(capabilities).to_have_attribute("open", "")
    url = form.get_by_label("URL de Moonraker")
    expect(url).to_have_attribute("aria-invalid", "true")
    expect(url).to_have_attribute("aria-describedby", "pf-moonraker_url-error")
    expect(form.get_by_label("Nombre")).to_be_focused()
    expect(form.locator(".form-error")).to_be_hidden()
    page.screenshot(path=str(ARTIFACTS / "printer-form-field-errors-es.png"))

    # Fixed, but the id is taken: a 422 without fields, so its reason is shown on top, in
    # the page's language.
    taken = api.post("/api/printers", json={**body, "id": "fleet-a", "name": "X",
                                            "moonraker_url": fleet_stacks[0].url,
                                            "capabilities": {}})  # fmt: skip
    assert taken.status_code == 422, taken.text
    assert not taken.json()["error"].get("fields")
    form.get_by_label("Nombre").fill("X")
    form.get_by_label("Identificador", exact=True).fill("fleet-a")
    url.fill(fleet_stacks[0].url)
    form.get_by_label("Boquilla (mm)").fill("")
    form.get_by_role("button", name="Añadir impresora").click()
    [reason] = taken.json()["error"]["reasons"]
    expect(form.locator(".form-error")).to_have_text(reason["es"])
    expect(form.locator(".form-error")).to_contain_text("Ya existe una impresora")
    for error in (url_error, nozzle_error, form.locator("#pf-name-error")):
        expect(error).to_be_hidden()
    expect(url).not_to_have_attribute("aria-invalid", "true")
    form.get_by_role("button", name="Volver").click()
    expect(form).to_be_hidden()
    assert len(api.get("/api/printers").json()) == 3


@pytest.mark.usefixtures("forget_new_printer")
def test_a_printer_that_does_not_answer_is_saved_only_when_asked(
    page: Page,
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    fleet_stacks: list[PrinterStack],
    console_errors: ConsoleErrors,
) -> None:
    open_fleet(page, kybercore_server.url)
    page.get_by_role("button", name="Add printer").click()
    form = page.get_by_role("dialog", name="Add a printer")
    form.get_by_label("Name").fill("Switched Off")
    form.get_by_label("Id", exact=True).fill(NEW_ID)

    # The same Moonraker as a printer of the fleet: refused, saying which printer has it.
    console_errors.expect(r"status of 422 .*/api/printers\?check=true\]$")
    form.get_by_label("Moonraker URL").fill(fleet_stacks[0].url)
    form.get_by_role("button", name="Add printer").click()
    expect(form.locator(".form-error")).to_contain_text("already uses")
    expect(form.locator(".form-error")).to_contain_text("fleet-a")

    # Nothing answers there: the connection test says so, and nothing is saved...
    console_errors.expect(r"status of 503 .*/api/printers\?check=true\]$")
    dead = f"http://127.0.0.1:{free_port()}"
    form.get_by_label("Moonraker URL").fill(dead)
    form.get_by_role("button", name="Add printer").click()
    expect(form.locator(".form-error")).to_contain_text("The connection test failed")
    anyway = form.get_by_label("Save anyway: connect when the printer comes online")
    expect(anyway).to_be_focused()
    assert api.get(f"/api/printers/{NEW_ID}").status_code == 404

    # ... until the operator says to save it anyway: it is added, offline.
    anyway.check()
    form.get_by_role("button", name="Add printer").click()
    expect(form).to_be_hidden()
    expect(page.locator(".toast.warn")).to_contain_text("not reachable yet")
    expect(tile(page, NEW_ID).locator(".badge.conn")).to_have_text("Offline", timeout=20_000)
    assert api.get(f"/api/printers/{NEW_ID}").json()["moonraker_url"] == dead
