"""Files: list, drag-and-drop upload with progress, and one file to several printers."""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest
from playwright.sync_api import FilePayload, Page, expect

from kybercore.sim.stack import PrinterStack
from tests.helpers import KyberCoreServer
from tests.web.support import open_fleet, slow_print, tile

pytestmark = pytest.mark.browser

DROPPED = "web_dropped.gcode"
SHARED = "web_shared.gcode"


@pytest.fixture
def remove_uploads(fleet_stacks: list[PrinterStack]) -> Iterator[None]:
    yield
    for stack in fleet_stacks:
        for name in (DROPPED, SHARED):
            (stack.gcodes_dir / name).unlink(missing_ok=True)


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
    # Staggered: one printer after the other. (Also needed here: the virtual printers'
    # Moonrakers share /tmp and collide on their upload temp file names when in parallel.)
    dialog.get_by_label("Seconds between starts").fill("1")
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
    preview = page.get_by_role("dialog", name="Cancel print: 2 printer(s)")
    expect(preview).to_contain_text("Every selected printer can do this now.")
    preview.get_by_role("button", name="Cancel print on 2").click()
    results = page.get_by_role("dialog", name="Cancel print: results")
    expect(results).to_contain_text("Done on 2 of 2 printers.")
    for printer_id in ("fleet-a", "fleet-b"):
        expect(results.locator(f"[data-printer={printer_id}]")).to_contain_text("Print cancelled.")
        expect(tile(page, printer_id).locator(".pill")).to_have_text("Cancelled")
        assert api.get(f"/api/printers/{printer_id}").json()["job"]["state"] == "cancelled"
