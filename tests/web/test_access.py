"""With tokens, the dashboard asks for one, and a viewer's page only watches."""

from __future__ import annotations

import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from playwright.sync_api import Page, expect

from kybercore.api.auth import TokenStore, tokens_path_for
from kybercore.sim.stack import free_port
from tests.helpers import KyberCoreServer
from tests.web.conftest import ConsoleErrors
from tests.web.support import FLEET, tile

pytestmark = pytest.mark.browser


@pytest.fixture
def guarded_server(kybercore_server: KyberCoreServer, tmp_path: Path) -> Iterator[tuple[str, str]]:
    """A second `kybercore serve` for the same printers, with a viewer token: (url, token)."""
    printers_file = tmp_path / "printers.json"
    shutil.copyfile(kybercore_server.printers_file, printers_file)
    _, token = TokenStore(tokens_path_for(printers_file)).create("web-viewer", "viewer")
    server = KyberCoreServer(printers_file, free_port())
    server.start()
    try:
        yield server.url, token
    finally:
        server.stop()


def test_a_viewer_logs_in_and_can_only_watch(
    new_page: Callable[..., Page],
    guarded_server: tuple[str, str],
    request: pytest.FixtureRequest,
) -> None:
    url, token = guarded_server
    page = new_page()
    errors: ConsoleErrors = request.node.console_errors
    page.goto(url)
    login = page.get_by_role("dialog", name="Log in to KyberCore")
    expect(login).to_be_visible()
    expect(page.locator(".tile")).to_have_count(0)  # nothing shown before logging in

    errors.expect(r"status of 401 .*/api/session\]$")
    field = login.get_by_label("Token")
    field.fill("kc_not-a-real-token")
    login.get_by_role("button", name="Log in").click()
    expect(login.get_by_role("alert")).to_have_text("That token is not valid. Check it and retry.")

    field.fill(token)
    login.get_by_role("button", name="Log in").click()
    expect(login).to_be_hidden()
    page.locator("#live[data-state=live]").wait_for()
    expect(page.locator(".tile")).to_have_count(len(FLEET))
    expect(page.locator("#who")).to_contain_text("web-viewer · viewer")
    expect(page.get_by_role("button", name="Add printer")).to_be_hidden()
    expect(page.get_by_role("link", name="Audit log")).to_be_hidden()  # admins only

    card = tile(page, "fleet-a")
    expect(card.locator(".badge.conn")).to_have_text("Online", timeout=20_000)
    expect(card.locator("[data-action=pause]")).to_be_disabled()
    expect(card.locator("[data-action=emergency_stop]")).to_be_disabled()
    expect(card.locator("[data-action=files]")).to_be_enabled()
    card.locator("[data-action=more]").click()
    for item in ("Home all axes", "Edit printer", "Remove printer"):
        expect(page.get_by_role("menuitem", name=item)).to_be_disabled()
    page.keyboard.press("Escape")

    # The console can be watched, not typed into.
    card.locator("[data-action=console]").click()
    drawer = page.get_by_role("dialog", name="Printer A")
    expect(drawer.get_by_role("textbox", name="G-code command")).to_be_disabled()
    expect(drawer).to_contain_text("Your role may only watch")
    drawer.get_by_role("button", name="Close").click()

    # Logging out forgets the cookie: the next page asks again.
    page.locator("#logout").click()
    expect(page.get_by_role("dialog", name="Log in to KyberCore")).to_be_visible()
    expect(page.locator(".tile")).to_have_count(0)
