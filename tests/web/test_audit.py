"""The Audit log in the dashboard, on a real server and real printers: an admin sees who did
what to which printer and how it ended, filters it, in Spanish too. A viewer's page has no
link to it (tests/web/test_access.py)."""

from __future__ import annotations

import uuid

import httpx
import pytest
from playwright.sync_api import Page, expect

from tests.helpers import KyberCoreServer
from tests.web.support import ARTIFACTS, inject_axe, open_fleet

pytestmark = [pytest.mark.integration, pytest.mark.browser]


def test_the_audit_log_shows_who_did_what_and_how_it_ended(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    tag = uuid.uuid4().hex[:8].upper()
    # One command that runs and one KyberCore refuses (past the hotend's limit), both
    # recorded with their outcome.
    done = api.post("/api/printers/fleet-a/gcode", json={"script": f"M115 ; audit {tag}"})
    assert done.status_code == 200, done.text
    refused = api.post("/api/printers/fleet-b/gcode", json={"script": f"M104 S999 ; {tag}"})
    assert refused.status_code == 422, refused.text
    refused_code = refused.json()["error"]["code"]

    open_fleet(page, kybercore_server.url)
    page.get_by_role("link", name="Audit log").click()
    view = page.locator("#audit-view")
    expect(view.get_by_role("heading", name="Audit log")).to_be_visible()
    expect(page.locator("#fleet")).to_be_hidden()

    ok_row = view.locator(f'tr:has-text("audit {tag}")')
    expect(ok_row).to_have_count(1)
    expect(ok_row.locator("td").nth(1)).to_have_text("local · admin")
    expect(ok_row.locator("td").nth(2)).to_have_text("printer.gcode")
    expect(ok_row.locator("td").nth(3)).to_have_text("printer:fleet-a")
    expect(ok_row.locator(".pill")).to_have_text("OK")
    refused_row = view.locator(f'tr:has-text("S999 ; {tag}")')
    expect(refused_row.locator(".pill")).to_have_text(refused_code)
    expect(refused_row.locator("td").nth(3)).to_have_text("printer:fleet-b")
    page.screenshot(path=str(ARTIFACTS / "audit.png"))

    # Filtered by target: only fleet-b's actions, counted as the API counts them.
    view.get_by_label("Target").fill("printer:fleet-b")
    total = api.get("/api/audit", params={"target": "printer:fleet-b"}).json()["total"]
    expect(view).to_have_attribute("data-total", str(total))
    targets = view.locator("tbody tr td:nth-child(4)")
    expect(targets.first).to_have_text("printer:fleet-b")
    assert set(targets.all_inner_texts()) == {"printer:fleet-b"}
    expect(ok_row).to_have_count(0)

    page.locator("#lang").select_option("es")
    expect(view.get_by_role("heading", name="Registro de auditoría")).to_be_visible()
    expect(refused_row.locator("td").nth(1)).to_have_text("local · administrador")

    # On a narrow screen the table scrolls sideways: the keyboard must reach it (axe's rule).
    page.set_viewport_size({"width": 480, "height": 900})
    wrap = view.locator(".table-wrap")
    assert wrap.evaluate("el => el.scrollWidth > el.clientWidth"), "the table should scroll here"
    inject_axe(page)
    found = page.evaluate(
        "async () => (await axe.run('#audit-view', {runOnly: ['scrollable-region-focusable']}))"
        ".violations.map(v => v.id)"
    )
    assert found == []
