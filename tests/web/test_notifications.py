"""The Notifications page, on the real server: a webhook channel added from the page gets a
signed test message on a loopback receiver and the page's delivery log shows it delivered;
the backend's refusals show next to their fields; noise control is saved in the units an
operator thinks in; the page speaks Spanish, asks before deleting, and fits a phone."""

from __future__ import annotations

import asyncio
import re
import threading
import uuid
from collections.abc import Callable, Iterator
from typing import Any

import httpx
import pytest
from playwright.sync_api import Locator, Page, expect

from kybercore.notify.senders import EVENT_HEADER, SIGNATURE_HEADER, TIMESTAMP_HEADER, verify
from tests.helpers import KyberCoreServer, wait_until
from tests.notify.receiver import Receiver
from tests.web.conftest import ConsoleErrors
from tests.web.support import ARTIFACTS, open_fleet

pytestmark = [pytest.mark.integration, pytest.mark.browser]

CHANNELS = "/api/notifications/channels"
SETTINGS = "/api/notifications/settings"


@pytest.fixture
def receiver() -> Iterator[Receiver]:
    """The loopback webhook receiver of tests/notify, served from a thread with an event
    loop of its own (the browser tests are synchronous)."""
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, name="receiver", daemon=True)
    thread.start()
    hook = Receiver()
    asyncio.run_coroutine_threadsafe(hook.start(), loop).result(timeout=30)
    try:
        yield hook
    finally:
        asyncio.run_coroutine_threadsafe(hook.stop(), loop).result(timeout=30)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(timeout=30)
        loop.close()


@pytest.fixture
def channel_name(api: httpx.Client) -> Iterator[str]:
    """A name of this test's own; the channels named so are removed afterwards (the
    server is shared by every browser test)."""
    name = f"Night shift {uuid.uuid4().hex[:6]}"
    yield name
    for channel in api.get(CHANNELS).json():
        if channel["name"].startswith(name):
            api.delete(f"{CHANNELS}/{channel['id']}")


@pytest.fixture
def noise_settings(api: httpx.Client) -> Iterator[dict[str, Any]]:
    """The noise settings as they were; put back afterwards."""
    before = api.get(SETTINGS).json()
    yield before
    assert api.put(SETTINGS, json=before).status_code == 200


def open_notifications(page: Page, url: str) -> Locator:
    """Load the dashboard and go to its Notifications page (from the navigation)."""
    open_fleet(page, url)
    page.get_by_role("link", name=re.compile("^(Notifications|Notificaciones)$")).click()
    view = page.locator("#notifications-view")
    expect(view).to_be_visible()
    return view


def channel_card(view: Locator, name: str) -> Locator:
    return view.locator(".nt-channel", has=view.page.get_by_role("heading", name=name, exact=True))


def test_a_webhook_added_from_the_page_gets_a_signed_test_message(
    page: Page,
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    receiver: Receiver,
    channel_name: str,
) -> None:
    view = open_notifications(page, kybercore_server.url)
    expect(view.get_by_role("heading", name="Notifications", exact=True)).to_be_visible()
    expect(page.locator("#fleet")).to_be_hidden()

    view.get_by_role("button", name="Add channel").click()
    form = page.get_by_role("dialog", name="Add a notification channel")
    expect(form.get_by_label("Webhook (JSON, signed)")).to_be_checked()
    form.get_by_label("Name", exact=True).fill(channel_name)
    form.get_by_label("URL", exact=True).fill(receiver.url("/hook"))
    # Events by severity, labelled by the backend; the defaults ticked.
    critical = form.get_by_role("group", name="Critical")
    expect(critical.get_by_label("Print failed")).to_be_checked()
    expect(form.get_by_label("First layer done")).not_to_be_checked()
    form.get_by_label("Printer A").check()
    form.get_by_label("Hold messages back during quiet hours").check()
    form.get_by_label("From").fill("23:00")
    form.get_by_label("Until").fill("06:30")
    page.screenshot(path=str(ARTIFACTS / "notifications-form.png"))
    form.get_by_role("button", name="Add channel").click()

    # The generated secret, shown this once.
    shown = page.get_by_role("dialog", name=f"Webhook secret for {channel_name}")
    expect(shown).to_contain_text("cannot show it again")
    secret = shown.get_by_label("Secret", exact=True).input_value()
    assert len(secret) >= 32
    shown.get_by_role("button", name="Copy").click()
    expect(shown.get_by_role("status")).to_have_text("Copied to the clipboard.")
    shown.get_by_role("button", name="Done").click()
    expect(shown).to_be_hidden()

    card = channel_card(view, channel_name)
    expect(card).to_contain_text(receiver.url("/hook"))
    expect(card).to_contain_text("Printers: Printer A")
    expect(card).to_contain_text("23:00–06:30 · critical alerts still come through")
    stored = next(c for c in api.get(CHANNELS).json() if c["name"] == channel_name)
    assert stored["rules"]["printers"] == ["fleet-a"]
    assert stored["rules"]["quiet_hours"] == {
        "start": "23:00",
        "end": "06:30",
        "allow_critical": True,
    }
    assert stored["has_secret"] is True
    assert secret not in str(stored)

    card.get_by_role("button", name="Send test").click()
    expect(card.get_by_role("status")).to_have_text("Test delivered (HTTP 200).")

    log = view.locator(f'.nt-log tr[data-channel="{stored["id"]}"]')
    expect(log).to_have_count(1)
    expect(log).to_have_attribute("data-status", "delivered")
    expect(log.locator(".pill")).to_have_text("Delivered")
    expect(log).to_contain_text(channel_name)

    # The receiver got it once, signed with the secret the page showed.
    assert len(receiver.requests) == 1, receiver.requests
    request = receiver.requests[0]
    assert (request.method, request.path) == ("POST", "/hook")
    assert request.headers[EVENT_HEADER.lower()] == "test"
    assert verify(
        secret,
        request.headers[TIMESTAMP_HEADER.lower()],
        request.body,
        request.headers[SIGNATURE_HEADER.lower()],
    )
    assert not verify("not the secret at all", request.headers[TIMESTAMP_HEADER.lower()],
                      request.body, request.headers[SIGNATURE_HEADER.lower()])  # fmt: skip
    page.screenshot(path=str(ARTIFACTS / "notifications.png"), full_page=True)


def test_the_backends_refusals_show_next_to_their_fields(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client, channel_name: str,
    console_errors: ConsoleErrors,
) -> None:  # fmt: skip
    console_errors.expect(r"status of 422 .*/api/notifications/channels\]$")
    view = open_notifications(page, kybercore_server.url)
    view.get_by_role("button", name="Add channel").click()
    form = page.get_by_role("dialog", name="Add a notification channel")
    form.get_by_label("Name", exact=True).fill(channel_name)
    form.get_by_label("URL", exact=True).fill("ftp://files.example/hook")
    form.get_by_label("Webhook secret").fill("too-short")
    form.get_by_role("button", name="Add channel").click()
    secret_box = form.locator('[data-field="secret"]')
    expect(secret_box.locator(".field-error")).to_contain_text("at least 16 characters")
    expect(form.get_by_label("Webhook secret")).to_have_attribute("aria-invalid", "true")

    form.get_by_label("Webhook secret").fill("")
    form.get_by_role("button", name="Add channel").click()
    url_box = form.locator('[data-field="target"]')
    expect(url_box.locator(".field-error")).to_contain_text("http:// or https://")
    expect(form.get_by_label("URL", exact=True)).to_have_attribute("aria-invalid", "true")
    expect(secret_box.locator(".field-error")).to_be_hidden()

    # Fixed, it goes through; nothing was stored by the refused attempt.
    form.get_by_label("URL", exact=True).fill("https://hooks.example/kybercore")
    form.get_by_role("button", name="Add channel").click()
    page.get_by_role("dialog", name=f"Webhook secret for {channel_name}").get_by_role(
        "button", name="Done"
    ).click()
    expect(channel_card(view, channel_name)).to_be_visible()
    assert [c["name"] for c in api.get(CHANNELS).json()].count(channel_name) == 1


def test_noise_control_is_saved_in_minutes(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client,
    noise_settings: dict[str, Any],
) -> None:  # fmt: skip
    view = open_notifications(page, kybercore_server.url)
    settings = view.get_by_role("region", name="Noise control")
    cooldown = settings.get_by_label("Repeat the same alert for a printer at most every")
    expect(cooldown).to_have_value(f"{noise_settings['cooldown_s'] / 60:g}")
    cooldown.fill("12.5")
    settings.get_by_label("Alert when a plate waits to be cleared longer than").fill("45")
    settings.get_by_role("button", name="Save noise control").click()
    expect(settings.get_by_role("status")).to_have_text("Noise control saved.")
    saved = api.get(SETTINGS).json()
    assert saved["cooldown_s"] == 750
    assert saved["plate_wait_s"] == 2700
    assert saved["fold_window_s"] == noise_settings["fold_window_s"]


def test_in_spanish_and_a_delete_asks_first(
    new_page: Callable[..., Page],
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    channel_name: str,
) -> None:
    answer = api.post(
        CHANNELS,
        json={
            "name": channel_name,
            "kind": "webhook",
            "target": "https://hooks.example/kybercore?token=hidden",
            "rules": {"events": ["print_failed", "printer_offline"], "min_role": "operator"},
        },
    )
    assert answer.status_code == 201, answer.text
    channel_id = answer.json()["id"]
    page = new_page(locale="es-ES")
    view = open_notifications(page, kybercore_server.url)
    expect(page.get_by_role("link", name="Notificaciones")).to_have_attribute(
        "aria-current", "page"
    )
    expect(view.get_by_role("heading", name="Notificaciones", exact=True)).to_be_visible()
    for heading in ("Canales", "Registro de envíos", "Control del ruido"):
        expect(view.get_by_role("heading", name=heading)).to_be_visible()
    card = channel_card(view, channel_name)
    # The target's token is not shown; the events are named in Spanish.
    expect(card).to_contain_text("https://hooks.example/kybercore")
    expect(card).not_to_contain_text("hidden")
    expect(card).to_contain_text("Impresión fallida, Impresora desconectada")
    expect(card).to_contain_text("Todas las impresoras")

    card.get_by_role("button", name="Editar").click()
    form = page.get_by_role("dialog", name=f"Editar {channel_name}")
    critical = form.get_by_role("group", name="Críticos")
    expect(critical.get_by_label("Impresión fallida")).to_be_checked()
    expect(form.get_by_role("group", name="Avisos")).to_be_visible()
    form.get_by_role("group", name="Información").get_by_label("Impresión iniciada").check()
    form.get_by_role("button", name="Guardar").click()
    expect(form).to_be_hidden()
    expect(card).to_contain_text("Impresión fallida, Impresora desconectada, Impresión iniciada")
    rules = next(c for c in api.get(CHANNELS).json() if c["id"] == channel_id)["rules"]
    assert sorted(rules["events"]) == ["print_failed", "print_started", "printer_offline"]

    # Switched off from its card, and on again.
    card.get_by_label("Activo").uncheck()
    expect(card).to_have_attribute("data-enabled", "false")
    assert not next(c for c in api.get(CHANNELS).json() if c["id"] == channel_id)["enabled"]
    card.get_by_label("Activo").check()
    expect(card).to_have_attribute("data-enabled", "true")

    card.get_by_role("button", name="Eliminar").click()
    confirm = page.get_by_role("dialog", name=f"¿Eliminar {channel_name}?")
    expect(confirm).to_contain_text("No se puede deshacer")
    confirm.get_by_role("button", name="Volver").click()
    expect(confirm).to_be_hidden()
    expect(card).to_be_visible()
    assert any(c["id"] == channel_id for c in api.get(CHANNELS).json())

    card.get_by_role("button", name="Eliminar").click()
    confirm.get_by_role("button", name="Eliminar").click()
    expect(card).to_have_count(0)
    assert not any(c["id"] == channel_id for c in api.get(CHANNELS).json())
    # The focus stays on the page (the next channel, or the list's heading).
    assert page.evaluate("document.activeElement.closest('#notifications-view') !== null")


def test_the_page_fits_a_phone(
    new_page: Callable[..., Page],
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    channel_name: str,
) -> None:
    answer = api.post(
        CHANNELS,
        json={"name": channel_name, "kind": "apprise", "target": "json://127.0.0.1:9/notify"},
    )
    assert answer.status_code == 201, answer.text
    page = new_page(width=390, height=844)
    view = open_notifications(page, kybercore_server.url)
    expect(channel_card(view, channel_name)).to_be_visible()
    expect(view.get_by_role("heading", name="Delivery log")).to_be_visible()

    def overflow() -> int:
        return int(page.evaluate("document.documentElement.scrollWidth - window.innerWidth"))

    wait_until(lambda: overflow() <= 0, what="no sideways scrolling")
    page.screenshot(path=str(ARTIFACTS / "notifications-narrow.png"), full_page=True)
    view.get_by_role("button", name="Add channel").click()
    form = page.get_by_role("dialog", name="Add a notification channel")
    box = form.bounding_box()
    assert box is not None
    assert box["width"] <= 390
    assert overflow() <= 0
    page.screenshot(path=str(ARTIFACTS / "notifications-form-narrow.png"))


def test_the_log_follows_a_retry_and_polls_only_while_shown(
    page: Page,
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    receiver: Receiver,
    channel_name: str,
) -> None:
    receiver.refuse(lambda _request: True)
    answer = api.post(
        CHANNELS, json={"name": channel_name, "kind": "webhook", "target": receiver.url("/hook")}
    )
    assert answer.status_code == 201, answer.text
    # The page's timers run on Playwright's clock: time can be pushed on, no waiting.
    page.clock.install()
    view = open_notifications(page, kybercore_server.url)
    card = channel_card(view, channel_name)
    card.get_by_role("button", name="Send test").click()
    expect(card.get_by_role("status")).to_contain_text(re.compile(r"Not delivered yet: .*HTTP 500"))
    row = view.locator(f'.nt-log tr[data-channel="{answer.json()["id"]}"]')
    expect(row).to_have_attribute("data-status", "retrying")
    expect(row.locator(".pill")).to_have_text("Retrying")
    expect(row.locator(".nt-error")).to_contain_text("500")

    # The receiver is back: the outbox's retry gets through, and the log, polling, shows it.
    receiver.refuse(lambda _request: False)
    expect(row).to_have_attribute("data-status", "delivered", timeout=60_000)
    expect(row.locator(".pill")).to_have_text("Delivered")
    assert len(receiver.accepted) == 1

    # Count the log's requests in the page, as they are made (the network events that
    # report them may come later than the clock's run).
    page.evaluate(
        """() => {
            const fetchFirst = window.fetch;
            window.logPolls = 0;
            window.fetch = (url, ...rest) => {
                if (String(url).includes("/api/notifications/deliveries")) window.logPolls++;
                return fetchFirst(url, ...rest);
            };
        }"""
    )

    def polled_after(run_ms: int) -> int:
        """How many log requests the page makes while its clock moves ``run_ms`` on."""
        before = int(page.evaluate("window.logPolls"))
        page.clock.run_for(run_ms)
        return int(page.evaluate("window.logPolls")) - before

    def quiet() -> bool:
        """No log request in a few runs of the clock (a request in flight at the first
        would have set its next one up by the last)."""
        return all(polled_after(5_000) == 0 for _ in range(3))

    # Shown and visible, it polls (unless a request is in flight just then: run again).
    wait_until(lambda: polled_after(2_100) >= 1, what="the log polled")
    hide = """hidden => {
        Object.defineProperty(document, "hidden", { value: hidden, configurable: true });
        document.dispatchEvent(new Event("visibilitychange"));
    }"""
    page.evaluate(hide, True)
    assert quiet(), "the log polls while the tab is hidden"
    with page.expect_request(re.compile(r"/api/notifications/deliveries")):
        page.evaluate(hide, False)
    page.get_by_role("link", name="Queue").click()
    expect(view).to_be_hidden()
    assert quiet(), "the log polls while another page is shown"
