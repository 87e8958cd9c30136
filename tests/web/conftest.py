"""Browser fixtures: Debian's Chromium driven by Playwright's sync API against the real
``kybercore serve`` of tests/conftest.py and its three virtual printers.

Every page collects console errors and page errors; a test with one it did not announce
(``console_errors.expect(...)``, for an HTTP error it provokes on purpose) fails. JavaScript
exceptions can never be announced. Screenshots go to tests/artifacts/.
"""

from __future__ import annotations

import os
import re
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from playwright.sync_api import (
    Browser,
    BrowserContext,
    ConsoleMessage,
    Page,
    Playwright,
    expect,
    sync_playwright,
)

from tests.helpers import KyberCoreServer
from tests.web.support import ARTIFACTS, make_idle

CHROMIUM = Path("/usr/bin/chromium")

# A live change reaches the page within a few seconds (Moonraker, KyberCore, the browser):
# 15 s is that promise with the slack a CI machine shared with other work needs (the 5 s
# default failed there, the change arriving later but arriving).
expect.set_options(timeout=15_000)
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


class ConsoleErrors:
    """Console errors and page errors of one page."""

    def __init__(self, page: Page) -> None:
        self.page = page
        self.console: list[str] = []
        self.page_errors: list[str] = []
        self.expected: list[re.Pattern[str]] = []
        page.on("console", self._on_console)
        page.on("pageerror", lambda e: self.page_errors.append(f"{e.name}: {e.message}"))

    def _on_console(self, message: ConsoleMessage) -> None:
        if message.type == "error":
            url = message.location.get("url", "")
            self.console.append(f"{message.text} [{url}]")

    def expect(self, pattern: str) -> None:
        """Allow console errors matching ``pattern``: those the test provokes on purpose
        (an HTTP 4xx it asks for, a refused WebSocket while the backend is down)."""
        self.expected.append(re.compile(pattern))

    def unexpected(self) -> list[str]:
        if not self.page.is_closed():  # a test may close its pages as it goes
            self.page.evaluate("0")  # deliver events still in flight
        console = [e for e in self.console if not any(p.search(e) for p in self.expected)]
        return [f"page error: {e}" for e in self.page_errors] + [f"console: {e}" for e in console]


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Iterator[None]:
    """Fail the test (not its teardown) on a console or page error it did not expect;
    keep a screenshot of the page when a browser test fails."""
    try:
        result = yield
    except BaseException:
        _failure_screenshot(item)
        raise
    errors: ConsoleErrors | None = getattr(item, "console_errors", None)
    if errors is not None:
        problems = errors.unexpected()
        if problems:
            _failure_screenshot(item)
            pytest.fail("browser errors during the test:\n" + "\n".join(problems), pytrace=False)
    return result


def _failure_screenshot(item: pytest.Item) -> None:
    errors: ConsoleErrors | None = getattr(item, "console_errors", None)
    if errors is None:
        return
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    try:
        errors.page.screenshot(path=str(ARTIFACTS / f"failed-{item.name}.png"))
    except Exception as exc:  # a screenshot must not hide the real failure
        print(f"no failure screenshot: {exc}")


@pytest.fixture(scope="session")
def playwright_session() -> Iterator[Playwright]:
    if not CHROMIUM.exists():
        pytest.fail(f"{CHROMIUM} is missing: install Debian's chromium (scripts/bootstrap.sh).")
    with sync_playwright() as playwright:
        yield playwright


@pytest.fixture(scope="session")
def browser(playwright_session: Playwright) -> Iterator[Browser]:
    # Chromium puts its singleton socket under TMPDIR; a long TMPDIR passes the 108-byte
    # limit of Unix socket paths and the browser dies at launch.
    with tempfile.TemporaryDirectory(prefix="kc-", dir="/tmp") as short_tmp:
        browser = playwright_session.chromium.launch(
            executable_path=str(CHROMIUM),
            args=CHROMIUM_ARGS,
            headless=True,
            env={**os.environ, "TMPDIR": short_tmp},
        )
        yield browser
        browser.close()


@pytest.fixture
def new_page(browser: Browser, request: pytest.FixtureRequest) -> Iterator[Callable[..., Page]]:
    """Open pages in fresh contexts (own localStorage); each one's errors are checked."""
    contexts: list[BrowserContext] = []

    def open_page(
        width: int = 1440, height: int = 900, locale: str = "en-US", color_scheme: Any = "dark"
    ) -> Page:
        context = browser.new_context(
            viewport={"width": width, "height": height}, locale=locale, color_scheme=color_scheme
        )
        context.set_default_timeout(15_000)
        contexts.append(context)
        page = context.new_page()
        request.node.console_errors = ConsoleErrors(page)
        return page

    yield open_page
    for context in contexts:
        context.close()


@pytest.fixture
def page(new_page: Callable[..., Page]) -> Page:
    """A desktop-sized page, in English."""
    return new_page()


@pytest.fixture
def console_errors(request: pytest.FixtureRequest, page: Page) -> ConsoleErrors:
    """The error collector of ``page`` (to announce errors a test provokes)."""
    errors: ConsoleErrors = request.node.console_errors
    return errors


@pytest.fixture(scope="session")
def api(kybercore_server: KyberCoreServer) -> Iterator[httpx.Client]:
    """The REST API of the backend under test, for setting up and checking."""
    with httpx.Client(base_url=kybercore_server.url, timeout=30) as client:
        yield client


@pytest.fixture(autouse=True)
def idle_fleet(kybercore_server: KyberCoreServer, api: httpx.Client) -> Iterator[None]:
    """Every test starts and ends with fleet-a/b/c online, ready, idle and cold: the API
    tests share these printers."""
    make_idle(kybercore_server, api)
    yield
    make_idle(kybercore_server, api)
