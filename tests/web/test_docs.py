"""The API's own documentation pages work offline, under a CSP of their own."""

from __future__ import annotations

import httpx
import pytest
from playwright.sync_api import Page, expect

from tests.helpers import KyberCoreServer
from tests.web.conftest import ConsoleErrors

pytestmark = pytest.mark.browser

METHODS = {"get", "put", "post", "delete", "patch"}


def _operations(server: KyberCoreServer) -> int:
    paths = httpx.get(f"{server.url}/openapi.json").json()["paths"]
    return sum(len(METHODS & set(item)) for item in paths.values())


def test_swagger_ui_lists_every_operation(page: Page, kybercore_server: KyberCoreServer) -> None:
    answer = page.goto(f"{kybercore_server.url}/docs")
    assert answer is not None
    policy = answer.headers["content-security-policy"]
    assert "script-src 'self';" in policy
    assert "http" not in policy  # no CDN is allowed, none is needed
    operations = page.locator(".opblock-summary-path")
    expect(operations).to_have_count(_operations(kybercore_server))
    expect(operations.filter(has_text="/api/printers/{printer_id}/gcode")).to_be_visible()


def test_redoc_lists_the_operations(
    page: Page, kybercore_server: KyberCoreServer, console_errors: ConsoleErrors
) -> None:
    # ReDoc's footer asks the internet for a logo; the CSP says no, and ReDoc hides it.
    console_errors.expect(r"cdn\.redoc\.ly/redoc/logo-mini\.svg")
    page.goto(f"{kybercore_server.url}/redoc")
    expect(page.get_by_role("heading", name="KyberCore").first).to_be_visible()
    expect(page.get_by_text("/api/printers/{printer_id}/gcode").first).to_be_attached()
