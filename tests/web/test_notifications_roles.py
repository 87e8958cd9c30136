"""The Notifications page by role, on a server with tokens: a viewer reads noise control and
is not shown the channels; an operator sends tests and adds channels for operators, while an
admins' channel and noise control stay read-only."""

from __future__ import annotations

import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import Page, expect

from kybercore.api.auth import TokenStore, tokens_path_for
from kybercore.sim.stack import free_port
from tests.helpers import KyberCoreServer
from tests.web.conftest import ConsoleErrors
from tests.web.support import FLEET
from tests.web.test_notifications import CHANNELS, channel_card

pytestmark = [pytest.mark.integration, pytest.mark.browser]


@pytest.fixture
def guarded_server(kybercore_server: KyberCoreServer, tmp_path: Path) -> Iterator[dict[str, str]]:
    """A second `kybercore serve` for the same printers, with tokens: its url, and a token
    per role."""
    printers_file = tmp_path / "printers.json"
    shutil.copyfile(kybercore_server.printers_file, printers_file)
    store = TokenStore(tokens_path_for(printers_file))
    tokens = {
        role: store.create(f"web-{role}", role)[1] for role in ("admin", "operator", "viewer")
    }
    server = KyberCoreServer(printers_file, free_port())
    server.start()
    try:
        yield {"url": server.url, **tokens}
    finally:
        server.stop()


def log_in(page: Page, url: str, token: str) -> None:
    page.goto(url)
    login = page.get_by_role("dialog", name="Log in to KyberCore")
    login.get_by_label("Token").fill(token)
    login.get_by_role("button", name="Log in").click()
    expect(login).to_be_hidden()
    page.locator("#live[data-state=live]").wait_for()
    expect(page.locator(".tile")).to_have_count(len(FLEET))


def test_what_an_operator_and_a_viewer_may_change(
    new_page: Callable[..., Page], guarded_server: dict[str, str], request: pytest.FixtureRequest
) -> None:
    url = guarded_server["url"]
    with httpx.Client(
        base_url=url, headers={"Authorization": f"Bearer {guarded_server['admin']}"}
    ) as admin:
        answer = admin.post(
            CHANNELS,
            json={"name": "Admins' pager", "kind": "webhook", "target": "https://hooks.example/a"},
        )
    assert answer.status_code == 201, answer.text

    # A viewer reads noise control, and is told the channels are an operator's business
    # (without asking for them: a 403 would fail this test as a console error).
    page = new_page()
    log_in(page, url, guarded_server["viewer"])
    page.get_by_role("link", name="Notifications").click()
    view = page.locator("#notifications-view")
    expect(view).to_contain_text(
        "Channels and their delivery log are shown to operators and admins."
    )
    expect(view.get_by_role("button", name="Add channel")).to_be_disabled()
    expect(view.get_by_role("heading", name="Delivery log")).to_be_hidden()
    settings = view.get_by_role("region", name="Noise control")
    expect(
        settings.get_by_label("Repeat the same alert for a printer at most every")
    ).to_have_value("5")
    viewer_errors: ConsoleErrors = request.node.console_errors
    assert viewer_errors.unexpected() == []

    # An operator sends tests and adds channels for operators; an admins' channel and noise
    # control are read-only.
    page = new_page()
    log_in(page, url, guarded_server["operator"])
    page.get_by_role("link", name="Notifications").click()
    view = page.locator("#notifications-view")
    settings = view.get_by_role("region", name="Noise control")
    expect(settings.get_by_text("Only an admin can change these.")).to_be_visible()
    expect(
        settings.get_by_label("Repeat the same alert for a printer at most every")
    ).not_to_be_editable()
    expect(settings.get_by_role("button", name="Save noise control")).to_be_hidden()
    card = channel_card(view, "Admins' pager")
    expect(card.get_by_role("button", name="Send test")).to_be_enabled()
    for control in ("Edit", "Delete"):
        expect(card.get_by_role("button", name=control)).to_be_disabled()
    expect(card.get_by_label("Enabled")).to_be_disabled()
    view.get_by_role("button", name="Add channel").click()
    form = page.get_by_role("dialog", name="Add a notification channel")
    who = form.get_by_label("Who may change it")
    expect(who).to_have_value("operator")
    expect(who.locator("option[value=admin]")).to_be_disabled()
