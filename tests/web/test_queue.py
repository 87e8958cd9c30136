"""The job queue in the dashboard, against the real backend and printers: queue a job, watch
a copy dispatch, clear the plate from the printer's tile, see the next copy start; reorder,
ask why a job waits, cancel it."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from playwright.sync_api import Page, expect

from tests.helpers import KyberCoreServer, wait_until
from tests.web.support import open_fleet, slow_print, tile

pytestmark = pytest.mark.browser

LIVE = ("pending", "uploading", "starting", "printing", "paused")
PRINT_WITHIN = 90_000
"""ms: a copy dispatched, uploaded, started and printed (about 25 s of travel moves)."""


def jobs(api: httpx.Client, finished: bool = False) -> list[dict[str, Any]]:
    listed: list[dict[str, Any]] = api.get("/api/jobs", params={"finished": finished}).json()
    return listed


@pytest.fixture
def clean_queue(api: httpx.Client) -> Iterator[None]:
    """The queue running and empty, every plate clear, before and after the test."""
    yield
    api.post("/api/queue", json={"paused": False})
    for job in jobs(api):
        api.delete(f"/api/jobs/{job['id']}", params={"confirm": "true"})

    def quiet() -> bool:
        return not any(
            a["state"] in LIVE
            for job in jobs(api, finished=True)
            for a in api.get(f"/api/jobs/{job['id']}/attempts").json()
        )

    wait_until(quiet, timeout=60, what="no copy on a printer")
    for printer, gate in api.get("/api/gates").json().items():
        if gate["state"] == "awaiting_clear":
            api.post(f"/api/printers/{printer}/clear", json={"verdict": "bad"})
        elif gate["state"] != "available":
            api.post(f"/api/printers/{printer}/release")


def test_a_job_queued_in_the_dashboard_prints_copy_after_copy_as_plates_are_cleared(
    page: Page,
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    clean_queue: None,
    tmp_path: Path,
) -> None:
    gcode = tmp_path / "queue_web_part.gcode"
    gcode.write_bytes(slow_print(moves=10))
    open_fleet(page, kybercore_server.url)
    page.get_by_role("link", name="Queue").click()
    expect(page).to_have_url(re.compile(r"#queue$"))
    expect(page.locator("#queue-empty")).to_have_text(
        "No jobs in the queue. Add one with “Add job”."
    )

    page.get_by_role("button", name="Add job").click()
    dialog = page.get_by_role("dialog", name="Add a job to the queue")
    # No file yet: the form says so, and only that (no stray "null" after the message).
    dialog.get_by_role("button", name="Add to queue").click()
    expect(dialog.locator(".form-error")).to_have_text("Choose a file first.")
    dialog.locator("input[type=file]").set_input_files(str(gcode))
    dialog.get_by_label("Copies").fill("2")
    dialog.get_by_role("combobox", name="Printer").select_option("fleet-a")
    dialog.get_by_role("button", name="Add to queue").click()
    expect(dialog).to_be_hidden()
    expect(page.locator(".toast.ok", has_text="Queued 2 × queue_web_part.gcode.")).to_be_visible()

    # The first copy dispatches: the row counts it printing, the tile prints it.
    row = page.locator(".job-row", has_text="queue_web_part.gcode")
    expect(row.locator(".copies-text")).to_have_text(
        "0 done · 1 printing · 1 left of 2", timeout=PRINT_WITHIN
    )
    expect(row.locator(".pill")).to_have_text("Printing")
    expect(row.locator(".job-needs")).to_have_text("only Printer A")
    expect(page.locator("#queue-count")).to_have_text("1")
    page.get_by_role("link", name="Printers", exact=True).click()
    card = tile(page, "fleet-a")
    expect(card.locator(".file")).to_contain_text("queue_web_part.gcode", timeout=PRINT_WITHIN)

    # It ends: the plate awaits a clear, shown on the tile and counted at a glance.
    good = card.get_by_role("button", name="Plate cleared, print good — Printer A")
    expect(good).to_be_visible(timeout=PRINT_WITHIN)
    expect(card.locator(".gate-text")).to_contain_text("Plate to clear since")
    expect(page.locator('.count-chip[data-group="awaiting_clear"] strong')).to_have_text("1")
    assert api.get("/api/gates").json()["fleet-a"]["state"] == "awaiting_clear"
    # The queue says whose turn it is: the operator's (the second copy is pinned there).
    page.get_by_role("link", name="Queue").click()
    expect(row.locator(".copies-text")).to_have_text(
        "0 done · 0 printing · 1 to clear · 1 left of 2"
    )
    expect(row.locator(".pill")).to_have_text("Plate to clear")
    expect(page.locator("#queue-summary")).to_have_text(
        "1 job · 1 copy to start · 0 printing · 1 plate to clear"
    )
    # So does the printer's own page, with the same Good and Bad.
    page.get_by_role("link", name="Printers", exact=True).click()
    card.get_by_role("link", name="Printer A").click()
    print_card = page.locator("#pp-job")
    expect(print_card.locator(".gate-text")).to_contain_text("Plate to clear since")
    on_page = print_card.get_by_role("button", name="Plate cleared, print good — Printer A")
    expect(on_page).to_be_visible()
    page.get_by_role("link", name="All printers").click()

    # One click: the copy counts, and the next one starts on the cleared printer.
    good.click()
    expect(
        page.locator(".toast.ok", has_text="Plate cleared: the copy counts as done.")
    ).to_be_visible()
    expect(card.locator(".gate")).to_be_hidden()
    expect(page.locator('.count-chip[data-group="awaiting_clear"] strong')).to_have_text("0")
    wait_until(
        lambda: len(api.get(f"/api/jobs/{jobs(api)[0]['id']}/attempts").json()) == 2,
        timeout=PRINT_WITHIN / 1000,
        what="the second copy dispatched",
    )
    page.get_by_role("link", name="Queue").click()
    # The second copy prints, or has already printed on a fast machine.
    expect(row.locator(".copies-text")).to_have_text(
        re.compile(r"1 done · (1 printing|0 printing · 1 to clear) · 0 left of 2")
    )

    # The second copy ends; "Bad…" asks for a cause and sends the copy back.
    page.get_by_role("link", name="Printers", exact=True).click()
    bad = card.get_by_role("button", name="Plate cleared, print bad — Printer A")
    expect(bad).to_be_visible(timeout=PRINT_WITHIN)
    bad.click()
    ask = page.get_by_role("dialog", name="Bad print on Printer A")
    ask.get_by_label("What went wrong (optional)").fill("layer shift")
    ask.get_by_role("button", name="Plate empty: print it again").click()
    expect(page.locator(".toast.ok", has_text="the copy goes back to the queue")).to_be_visible()
    job_id = jobs(api)[0]["id"]
    verdicts = [a["cause"] for a in api.get(f"/api/jobs/{job_id}/attempts").json() if a["verdict"]]
    assert verdicts == ["", "layer shift"]


def test_jobs_are_reordered_by_dragging_explained_and_cancelled_with_a_confirmation(
    page: Page,
    kybercore_server: KyberCoreServer,
    api: httpx.Client,
    clean_queue: None,
) -> None:
    assert api.post("/api/queue", json={"paused": True}).status_code == 200
    for name in ("first_in_line.gcode", "second_in_line.gcode"):
        answer = api.post(
            "/api/jobs", files={"file": (name, slow_print(moves=4))}, data={"printer": "fleet-b"}
        )
        assert answer.status_code == 201, answer.text
    first, second = (j["id"] for j in jobs(api))

    open_fleet(page, f"{kybercore_server.url}/#queue")
    expect(page.locator("#queue-paused")).to_be_visible()
    rows = page.locator(".job-row .job-name")
    expect(rows).to_have_text(["first_in_line.gcode", "second_in_line.gcode"])

    # Drag the second job above the first: the backend's order follows.
    second_row = page.locator(f'.job-row[data-job-id="{second}"]')
    first_row = page.locator(f'.job-row[data-job-id="{first}"]')
    second_row.locator(".grip").drag_to(first_row, target_position={"x": 40, "y": 4})
    expect(rows).to_have_text(["second_in_line.gcode", "first_in_line.gcode"])
    assert [j["id"] for j in jobs(api)] == [second, first]
    # And back with the keyboard-reachable arrow.
    first_row.get_by_role("button", name="Move up — first_in_line.gcode").click()
    expect(rows).to_have_text(["first_in_line.gcode", "second_in_line.gcode"])

    # Why it waits: the queue is paused, said in the UI's language.
    first_row.get_by_role("button", name="Why waiting?").click()
    expect(first_row.locator(".job-details .reason").first).to_be_visible()
    page.select_option("#lang", "es")
    expect(first_row.get_by_role("button", name="¿Por qué espera?")).to_be_visible()
    expect(page.get_by_role("link", name="Cola")).to_be_visible()
    page.select_option("#lang", "en")

    # Cancel asks first; backing out keeps the job.
    first_row.get_by_role("button", name="Cancel job — first_in_line.gcode").click()
    confirm = page.get_by_role("dialog", name="Cancel the job first_in_line.gcode?")
    confirm.get_by_role("button", name="Back").click()
    assert first in [j["id"] for j in jobs(api)]
    first_row.get_by_role("button", name="Cancel job — first_in_line.gcode").click()
    confirm.get_by_role("button", name="Cancel job").click()
    expect(
        page.locator(".toast.ok", has_text="Job cancelled: first_in_line.gcode.")
    ).to_be_visible()
    expect(rows).to_have_text(["second_in_line.gcode"])
    assert [j["id"] for j in jobs(api)] == [second]


def test_a_printer_is_held_from_its_menu_and_released_from_its_tile(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client, clean_queue: None
) -> None:
    open_fleet(page, kybercore_server.url)
    card = tile(page, "fleet-c")
    card.locator("[data-action=more]").click()
    page.get_by_role("menuitem", name="Hold from the queue…").click()
    ask = page.get_by_role("dialog", name="Hold Printer C")
    ask.get_by_role("button", name="Hold").click()
    expect(ask.get_by_role("alert")).to_have_text("Say why: everyone sees it.")
    ask.get_by_label("Reason").fill("nozzle change")
    ask.get_by_role("button", name="Hold").click()
    expect(card.locator(".gate-text")).to_have_text("Held: nozzle change")
    gate = api.get("/api/gates").json()["fleet-c"]
    assert (gate["state"], gate["reason"]) == ("held", "nozzle change")

    card.get_by_role("button", name="Give Printer C back to the queue").click()
    expect(card.locator(".gate")).to_be_hidden()
    assert api.get("/api/gates").json()["fleet-c"]["state"] == "available"
