"""Files: list, drag-and-drop upload with progress, one file to several printers, delete."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import FilePayload, Page, Request, Route, expect

from tests.helpers import KyberCoreServer, wait_until
from tests.web.conftest import ConsoleErrors
from tests.web.support import (
    ARTIFACTS,
    FLEET,
    make_idle,
    open_fleet,
    slow_print,
    start_print,
    tile,
)

pytestmark = pytest.mark.browser

DROPPED = "web_dropped.gcode"
SHARED = "web_shared.gcode"
DOOMED = "web_delete_me.gcode"
PRINTING = "web_delete_printing.gcode"
FOREIGN = "web_foreign_model.gcode"
IN_FOLDER = "web_folder/web_in_folder.gcode"
UPLOADS = (DROPPED, SHARED, DOOMED, PRINTING, FOREIGN, IN_FOLDER)


def file_names(api: httpx.Client, printer_id: str) -> list[str]:
    answer = api.get(f"/api/printers/{printer_id}/files")
    assert answer.status_code == 200, answer.text
    return [f["path"] for f in answer.json()]


def upload(api: httpx.Client, printer_id: str, name: str, content: bytes) -> None:
    files = {"file": (name, content, "application/octet-stream")}
    answer = api.post(f"/api/printers/{printer_id}/files", files=files)
    assert answer.status_code == 201, answer.text


@pytest.fixture
def remove_uploads(kybercore_server: KyberCoreServer, api: httpx.Client) -> Iterator[None]:
    """The test's files are deleted through the API (idle first: a printed file is in use)."""
    yield
    make_idle(kybercore_server, api)
    for printer_id in FLEET:
        present = set(file_names(api, printer_id))
        for name in present.intersection(UPLOADS):
            answer = api.delete(f"/api/printers/{printer_id}/files", params={"path": name})
            assert answer.status_code == 204, answer.text


@pytest.mark.usefixtures("remove_uploads")
def test_a_file_in_a_folder_shows_its_thumbnail(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    """Moonraker names a file's thumbnails relative to the file's own folder, as for the
    queue's uploads in kybercore/: the list asks for them under that folder."""
    upload(api, "fleet-c", IN_FOLDER, slow_print(60))
    open_fleet(page, kybercore_server.url)
    tile(page, "fleet-c").locator("[data-action=files]").click()
    drawer = page.get_by_role("dialog", name="Printer C")
    image = drawer.locator(f'tr[data-file="{IN_FOLDER}"] .file-thumb img')
    expect(image).to_have_attribute("src", re.compile(r"path=web_folder%2F\.thumbs%2F"))
    wait_until(
        lambda: bool(image.evaluate("i => i.complete && i.naturalWidth > 0")),
        what="the thumbnail drawn",
    )


@pytest.mark.usefixtures("remove_uploads")
def test_drop_a_file_on_a_printer_and_see_it_listed(
    page: Page, kybercore_server: KyberCoreServer
) -> None:
    open_fleet(page, kybercore_server.url)
    tile(page, "fleet-c").locator("[data-action=files]").click()
    drawer = page.get_by_role("dialog", name="Printer C")
    expect(drawer.get_by_role("tab", name="Files")).to_have_attribute("aria-selected", "true")

    # A real drop event carrying a file, as a browser makes it from the desktop.
    content = slow_print(60).decode()
    transfer = page.evaluate_handle(
        """([name, text]) => {
            const transfer = new DataTransfer();
            transfer.items.add(new File([text], name, { type: 'text/plain' }));
            return transfer;
        }""",
        [DROPPED, content],
    )
    drawer.locator(".drop-zone").dispatch_event("drop", {"dataTransfer": transfer})
    expect(drawer.get_by_role("status").first).to_have_text(f"Uploaded {DROPPED}.")
    expect(drawer.get_by_role("progressbar", name="Upload progress")).to_have_attribute(
        "aria-valuenow", "100"
    )
    row = drawer.locator(f'tr[data-file="{DROPPED}"]')
    expect(row.locator(".c-size")).to_have_text(f"{len(content.encode()) / 1024:.1f} KB")
    expect(row.locator(".c-est")).to_have_text("2 min 30 s")  # from the file's metadata
    expect(row.get_by_role("button", name=f"Print {DROPPED}")).to_be_enabled()


@pytest.mark.usefixtures("remove_uploads")
def test_upload_one_file_to_several_printers_and_print_it(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    open_fleet(page, kybercore_server.url)
    for name in ("Printer A", "Printer B"):
        page.get_by_role("checkbox", name=f"Select {name}").check()
    bar = page.get_by_role("region", name="Bulk actions")
    bar.locator("[data-bulk=upload]").click()
    dialog = page.get_by_role("dialog", name="Upload to 2 printers")
    payload: FilePayload = {"name": SHARED, "mimeType": "text/plain", "buffer": slow_print(80)}
    dialog.locator("input[type=file]").set_input_files(payload)
    dialog.get_by_label("Start printing after the upload").check()
    # No stagger: both uploads and starts go out in parallel.
    expect(dialog.get_by_label("Seconds between starts")).to_have_value("0")
    dialog.get_by_role("button", name="Upload", exact=True).click()
    for printer_id in ("fleet-a", "fleet-b"):
        row = dialog.locator(f"[data-printer={printer_id}]")
        expect(row).to_contain_text(f"Uploaded {SHARED} and started printing it.")
        expect(row.get_by_role("progressbar")).to_have_attribute("aria-valuenow", "100")
        expect(tile(page, printer_id).locator(".pill")).to_have_text("Printing")
    dialog.get_by_role("button", name="Done").click()
    assert api.get("/api/printers/fleet-c").json()["job"]["state"] == "standby"

    # Cancel both from the bulk bar: dry run, confirmation, one result per printer.
    bar.locator("[data-bulk=cancel]").click()
    preview = page.get_by_role("dialog", name="Cancel print: 2 printers")
    expect(preview).to_contain_text("Every selected printer can do this now.")
    preview.get_by_role("button", name="Cancel print on 2").click()
    results = page.get_by_role("dialog", name="Cancel print: results")
    # Klipper cancels once the move in progress ends (2.5 s here); a busy host adds more.
    expect(results).to_contain_text("Done on 2 of 2 printers.", timeout=30_000)
    for printer_id in ("fleet-a", "fleet-b"):
        expect(results.locator(f"[data-printer={printer_id}]")).to_contain_text("Print cancelled.")
        expect(tile(page, printer_id).locator(".pill")).to_have_text("Cancelled")
        assert api.get(f"/api/printers/{printer_id}").json()["job"]["state"] == "cancelled"


@pytest.mark.usefixtures("remove_uploads")
def test_a_file_deleted_from_the_ui_is_gone_from_the_printer(
    page: Page,
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    console_errors: ConsoleErrors,
) -> None:
    upload(api, "fleet-b", DOOMED, slow_print(20))
    start_print(api, "fleet-b", PRINTING)
    open_fleet(page, kybercore_server.url)
    tile(page, "fleet-b").locator("[data-action=files]").click()
    drawer = page.get_by_role("dialog", name="Printer B")
    row = drawer.locator(f'tr[data-file="{DOOMED}"]')
    delete = row.get_by_role("button", name=f"Delete {DOOMED}")
    expect(delete).to_be_enabled()
    drawer.screenshot(path=str(ARTIFACTS / "files-delete-buttons.png"))

    # It asks first; Back (which has the focus) leaves the file alone.
    delete.click()
    confirm = page.get_by_role("dialog", name=f"Delete {DOOMED}?")
    expect(confirm).to_contain_text("The file is deleted from Printer B.")
    expect(confirm.get_by_role("button", name="Back")).to_be_focused()
    page.screenshot(path=str(ARTIFACTS / "files-delete-confirm.png"))
    confirm.get_by_role("button", name="Back").click()
    expect(confirm).to_be_hidden()
    assert DOOMED in file_names(api, "fleet-b")

    delete.click()
    confirm.get_by_role("button", name="Delete").click()
    expect(page.locator(".toast.ok", has_text=f"Deleted {DOOMED}.")).to_be_visible()
    expect(row).to_have_count(0)
    assert DOOMED not in file_names(api, "fleet-b")
    expect(drawer.get_by_role("searchbox", name="Filter files")).to_be_focused()

    # The file being printed is refused (409 file_in_use) with the backend's words.
    refusal = api.delete("/api/printers/fleet-b/files", params={"path": PRINTING})
    assert refusal.status_code == 409, refusal.text
    assert refusal.json()["error"]["code"] == "file_in_use"
    console_errors.expect(r"status of 409 .*/api/printers/fleet-b/files\?path=")
    drawer.get_by_role("button", name=f"Delete {PRINTING}").click()
    in_use = page.get_by_role("dialog", name=f"Delete {PRINTING}?")
    in_use.get_by_role("button", name="Delete").click()
    toast = page.locator(".toast.error")
    expect(toast).to_contain_text(refusal.json()["error"]["message"])
    expect(toast).to_contain_text("Printer B · Delete")
    expect(drawer.locator(f'tr[data-file="{PRINTING}"]')).to_have_count(1)
    assert PRINTING in file_names(api, "fleet-b")
    assert api.get("/api/printers/fleet-b").json()["job"]["state"] == "printing"


@pytest.mark.usefixtures("remove_uploads")
def test_upload_and_print_asks_about_the_backends_warnings_then_confirms(
    page: Page,
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    console_errors: ConsoleErrors,
) -> None:
    # Sliced for another machine: starting it needs confirmation (printer_model_mismatch).
    content = slow_print(60) + b"; printer_model = Bambu X1C\n"
    sent: list[Request] = []
    page.on("request", lambda r: sent.append(r) if "/api/printers/fleet-b/" in r.url else None)
    open_fleet(page, kybercore_server.url)
    tile(page, "fleet-b").locator("[data-action=files]").click()
    drawer = page.get_by_role("dialog", name="Printer B")
    drawer.get_by_label("Start printing after the upload").check()
    payload: FilePayload = {"name": FOREIGN, "mimeType": "text/plain", "buffer": content}
    drawer.locator("input[type=file]").set_input_files(payload)

    warnings = page.get_by_role("dialog", name="Warnings for Printer B")
    expect(warnings).to_be_visible()
    # The upload happened (201); the dialog shows the reasons its refused start carried.
    verdict = api.post("/api/printers/fleet-b/actions/start/check", json={"filename": FOREIGN})
    reasons = [r for r in verdict.json()["reasons"] if r["level"] == "warn"]
    assert [r["code"] for r in reasons] == ["printer_model_mismatch"]
    expect(warnings.locator(".reason")).to_have_text([reasons[0]["en"]])
    assert not [r for r in sent if "/check" in r.url]
    # Already uploaded while it asks: full bar, listed.
    expect(drawer.get_by_role("progressbar")).to_have_attribute("aria-valuenow", "100")
    expect(drawer.locator(f'tr[data-file="{FOREIGN}"]')).to_have_count(1)
    page.screenshot(path=str(ARTIFACTS / "upload-confirm-warnings.png"))
    warnings.get_by_role("button", name="Go ahead").click()

    expect(drawer.locator(".upload-status")).to_have_text(
        f"Uploaded {FOREIGN} and started printing it."
    )
    expect(tile(page, "fleet-b").locator(".pill")).to_have_text("Printing")
    posts = [r for r in sent if r.method == "POST"]
    assert [r.url.split("/fleet-b/")[1] for r in posts] == ["files", "actions/start"]
    assert json.loads(posts[1].post_data or "{}") == {"filename": FOREIGN, "confirm": True}


@pytest.mark.usefixtures("remove_uploads")
def test_requests_refused_before_they_are_read_show_the_backends_message(
    page: Page,
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    console_errors: ConsoleErrors,
    tmp_path: Path,
) -> None:
    open_fleet(page, kybercore_server.url)
    tile(page, "fleet-a").locator("[data-action=files]").click()
    drawer = page.get_by_role("dialog", name="Printer A")

    # 413 too_large: a file over 512 MiB (sparse: no disk used) is refused unread.
    huge = tmp_path / "web_huge.gcode"
    with huge.open("wb") as handle:
        handle.truncate(513 * 2**20)
    console_errors.expect(r"status of 413 .*/api/printers/fleet-a/files")
    drawer.locator("input[type=file]").set_input_files(huge)
    too_large = "The request is larger than 512 MiB: split the file or upload it to the printer"
    expect(drawer.locator(".upload-status")).to_contain_text(too_large, timeout=30_000)
    expect(page.locator(".toast.error", has_text=too_large)).to_be_visible()
    assert "web_huge.gcode" not in file_names(api, "fleet-a")

    # 403 cross_origin: what a proxy that rewrites the Host header gets (the Origin forged
    # here); the real backend answers, the page shows its message.
    upload(api, "fleet-a", DOOMED, slow_print(20))
    drawer.get_by_role("button", name="Refresh").click()

    def forged(route: Route) -> None:
        headers = {**route.request.headers, "origin": "http://elsewhere.example"}
        route.fulfill(response=route.fetch(headers=headers))

    page.route(re.compile(r"/api/printers/fleet-a/files\?path="), forged)
    console_errors.expect(r"status of 403 .*/api/printers/fleet-a/files\?path=")
    drawer.get_by_role("button", name=f"Delete {DOOMED}").click()
    confirm = page.get_by_role("dialog", name=f"Delete {DOOMED}?")
    confirm.get_by_role("button", name="Delete").click()
    refused = page.locator(".toast.error", has_text="Printer A · Delete")
    expect(refused).to_contain_text(
        "Requests that change printers must come from KyberCore's own page."
    )
    assert DOOMED in file_names(api, "fleet-a")


@pytest.mark.usefixtures("remove_uploads")
def test_staggered_starts_are_paced_by_the_server(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    open_fleet(page, kybercore_server.url)
    for name in ("Printer A", "Printer B"):
        page.get_by_role("checkbox", name=f"Select {name}").check()
    page.get_by_role("region", name="Bulk actions").locator("[data-bulk=upload]").click()
    dialog = page.get_by_role("dialog", name="Upload to 2 printers")
    payload: FilePayload = {"name": SHARED, "mimeType": "text/plain", "buffer": slow_print(80)}
    dialog.locator("input[type=file]").set_input_files(payload)
    dialog.get_by_label("Start printing after the upload").check()
    dialog.get_by_label("Seconds between starts").fill("2")
    with page.expect_request(
        lambda r: r.url.endswith("/api/fleet/actions/start") and r.method == "POST"
    ) as started:
        dialog.get_by_role("button", name="Upload", exact=True).click()
    # One request: the server keeps the pace, not this page.
    assert started.value.post_data_json["stagger_seconds"] == 2
    for printer_id in ("fleet-a", "fleet-b"):
        row = dialog.locator(f"[data-printer={printer_id}]")
        expect(row).to_contain_text(f"Uploaded {SHARED} and started printing it.", timeout=30_000)
        expect(tile(page, printer_id).locator(".pill")).to_have_text("Printing")
    dialog.get_by_role("button", name="Done").click()
    cancel = api.post("/api/fleet/actions/cancel", json={"printer_ids": ["fleet-a", "fleet-b"]})
    assert [r["ok"] for r in cancel.json()["results"]] == [True, True], cancel.text
