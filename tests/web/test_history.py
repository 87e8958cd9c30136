"""The ledger in the dashboard, on real printers: History (filter by printer, download the
CSV), Statistics (graphs drawn from the real figures) and a printer's temperature graph."""

from __future__ import annotations

import csv
import io
import re
import uuid

import httpx
import pytest
from playwright.sync_api import Locator, Page, Route, WebSocketRoute, expect

from tests.helpers import KyberCoreServer, wait_until
from tests.web.support import ARTIFACTS, open_fleet, start_print, tile, wait_in_page

pytestmark = [pytest.mark.integration, pytest.mark.browser]


class Jobs:
    """The files of one test's two jobs, named after a tag of its own."""

    def __init__(self) -> None:
        self.tag = uuid.uuid4().hex[:8]
        self.done = f"done_{self.tag}.gcode"
        self.cancelled = f"cancelled_{self.tag}.gcode"


def job_state(api: httpx.Client, printer_id: str) -> str:
    return str(api.get(f"/api/printers/{printer_id}").json()["job"]["state"])


def history_total(api: httpx.Client, **filters: str) -> int:
    answer = api.get("/api/history", params=filters)
    assert answer.status_code == 200, answer.text
    return int(answer.json()["total"])


@pytest.fixture
def two_jobs(api: httpx.Client) -> Jobs:
    """A print completed on fleet-a and one cancelled on fleet-b, in the ledger."""
    jobs = Jobs()
    start_print(api, "fleet-a", jobs.done, moves=4)
    start_print(api, "fleet-b", jobs.cancelled, moves=120)
    wait_until(lambda: job_state(api, "fleet-b") == "printing", what="fleet-b printing")
    assert api.post("/api/printers/fleet-b/actions/cancel", json={}).status_code == 200
    wait_until(lambda: job_state(api, "fleet-a") == "complete", timeout=60, what="fleet-a done")
    wait_until(
        lambda: (
            history_total(api, file=jobs.tag) == 2
            and history_total(api, file=jobs.tag, status="completed") == 1
        ),
        timeout=30,
        what="both jobs in the ledger",
    )
    return jobs


def nonblank_pixels(chart: Locator) -> int:
    """How many pixels of the chart's canvas something was drawn on."""
    return int(
        chart.locator("canvas").evaluate(
            """canvas => {
                const data = canvas.getContext('2d')
                    .getImageData(0, 0, canvas.width, canvas.height).data;
                let drawn = 0;
                for (let i = 3; i < data.length; i += 4) if (data[i] > 0) drawn++;
                return drawn;
            }"""
        )
    )


def test_history_filters_by_printer_and_downloads_the_csv(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client, two_jobs: Jobs
) -> None:
    done_file, cancelled_file = two_jobs.done, two_jobs.cancelled
    open_fleet(page, kybercore_server.url)
    page.get_by_role("link", name="History").click()
    view = page.locator("#history-view")
    expect(view.get_by_role("heading", name="Job history")).to_be_visible()
    expect(page.locator("#fleet")).to_be_hidden()
    expect(view.locator(f'tr:has-text("{done_file}")')).to_have_count(1)
    expect(view.locator(f'tr:has-text("{cancelled_file}")')).to_have_count(1)

    view.get_by_label("Printer").select_option(label="Printer A")
    total_a = history_total(api, printer="fleet-a")
    expect(view).to_have_attribute("data-total", str(total_a))
    rows = view.locator("tbody tr")
    expect(rows).to_have_count(min(total_a, 50))
    assert set(rows.evaluate_all("rows => rows.map(r => r.dataset.printer)")) == {"fleet-a"}
    done = view.locator(f'tr:has-text("{done_file}")')
    expect(done.locator(".pill")).to_have_text("Completed")
    expect(view.locator(f'tr:has-text("{cancelled_file}")')).to_have_count(0)

    view.get_by_label("File").fill(two_jobs.tag)
    expect(rows).to_have_count(1)
    with page.expect_download() as download:
        view.get_by_role("link", name="Download CSV").click()
    text = download.value.path().read_text(encoding="utf-8")
    table = list(csv.DictReader(io.StringIO(text)))
    assert [(r["printer"], r["filename"], r["status"]) for r in table] == [
        ("fleet-a", done_file, "completed")
    ]
    page.screenshot(path=str(ARTIFACTS / "history.png"))

    # Spanish, like the rest of the dashboard.
    page.locator("#lang").select_option("es")
    expect(view.get_by_role("heading", name="Historial de trabajos")).to_be_visible()
    expect(done.locator(".pill")).to_have_text("Completado")


def test_a_job_recorded_without_its_file_says_so(
    page: Page, kybercore_server: KyberCoreServer
) -> None:
    """Moonraker records a job without its file name when it sees the print only end (a
    short print started while it was still subscribing after a Klippy restart, under
    load). The row says so instead of leaving the cell empty. The page gets a FAKE answer
    from /api/history: a real Moonraker does this only by chance, not on demand."""
    nameless = {
        "printer": "fleet-a", "moonraker_job_id": "000001", "filename": "", "sha256": None,
        "job_id": None, "attempt_id": None, "status": "completed", "queued_at": None,
        "started_at": "2026-11-28T10:00:00Z", "ended_at": "2026-11-28T10:00:05Z",
        "cleared_at": None, "verdict": None, "cause": None, "print_seconds": 5.0,
        "filament_mm": 0.0, "filament_g": None, "user": None,
    }  # fmt: skip

    def fake(route: Route) -> None:
        route.fulfill(json={"total": 1, "items": [nameless]})

    page.route(re.compile(r"/api/history\?"), fake)
    open_fleet(page, kybercore_server.url)
    page.get_by_role("link", name="History").click()
    file_cell = page.locator("#history-view tbody tr td.c-file")
    expect(file_cell).to_have_text("—")
    expect(file_cell).to_have_attribute(
        "title", "Moonraker recorded this job without its file name"
    )
    page.locator("#lang").select_option("es")
    expect(file_cell).to_have_attribute(
        "title", "Moonraker registró este trabajo sin el nombre de su archivo"
    )


def test_a_bookmarked_history_names_its_printers_once_the_fleet_arrives(
    page: Page, kybercore_server: KyberCoreServer
) -> None:
    """Opened at ``#history``, the page may list the jobs before the fleet's first frame
    says what the printers are called; the rows then show ids, and names once it does.
    The socket is held (not faked) until the rows are drawn, to make that order sure."""
    held: list[WebSocketRoute] = []
    page.route_web_socket(re.compile(r"/ws(\?.*)?$"), lambda ws: held.append(ws))
    row = {
        "printer": "fleet-a", "moonraker_job_id": "00000A", "filename": "part.gcode",
        "sha256": None, "job_id": None, "attempt_id": None, "status": "completed",
        "queued_at": None, "started_at": "2026-11-28T10:00:00Z",
        "ended_at": "2026-11-28T10:00:05Z", "cleared_at": None, "verdict": None,
        "cause": None, "print_seconds": 5.0, "filament_mm": 0.0, "filament_g": None,
        "user": None,
    }  # fmt: skip
    page.route(
        re.compile(r"/api/history\?"),
        lambda route: route.fulfill(json={"total": 1, "items": [row]}),
    )
    page.goto(f"{kybercore_server.url}/#history")
    name = page.locator("#history-view tbody tr td.c-name")
    expect(name).to_have_text("fleet-a")
    wait_in_page(page, lambda: bool(held), "the page to open its WebSocket")
    held[0].connect_to_server()
    expect(name).to_have_text("Printer A")
    expect(page.locator("#history-printer option", has_text="Printer A")).to_have_count(1)


@pytest.mark.usefixtures("two_jobs")
def test_statistics_draw_the_real_figures(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    open_fleet(page, kybercore_server.url)
    page.get_by_role("link", name="Statistics").click()
    view = page.locator("#stats-view")
    expect(view.get_by_role("heading", name="Statistics")).to_be_visible()
    utilisation = view.get_by_role("img", name="Utilisation per printer")
    per_day = view.get_by_role("img", name="Jobs per day by outcome")
    success = view.get_by_role("img", name="Success rate per printer")
    for chart in (utilisation, per_day, success):
        expect(chart.locator("canvas")).to_have_count(1)
        wait_until(lambda chart=chart: nonblank_pixels(chart) > 500, what="a drawn graph")
    # What they draw is what /api/stats says, per printer by name.
    rows = api.get("/api/stats", params={"group_by": "printer"}).json()["rows"]
    figures = {r["key"]: r for r in rows}
    assert {"fleet-a", "fleet-b"} <= set(figures)
    label = success.get_attribute("aria-label") or ""
    for printer_id, name in (("fleet-a", "Printer A"), ("fleet-b", "Printer B")):
        rate = figures[printer_id]["success_rate"]
        assert f"{name} {round(rate * 100)}%" in label, label
    today = api.get("/api/stats", params={"group_by": "day"}).json()["rows"][-1]
    assert today["jobs"].get("completed", 0) >= 1
    assert today["jobs"].get("cancelled", 0) >= 1
    day_label = per_day.get_attribute("aria-label") or ""
    assert f"{today['key']}: " in day_label
    assert f"{today['jobs']['completed']} Completed" in day_label
    assert f"{today['jobs']['cancelled']} Cancelled" in day_label
    assert int(utilisation.get_attribute("data-rows") or 0) == len(rows)
    view.screenshot(path=str(ARTIFACTS / "statistics.png"))


def test_the_printer_drawer_graphs_its_temperatures(
    page: Page, kybercore_server: KyberCoreServer, api: httpx.Client
) -> None:
    answer = api.post("/api/printers/fleet-c/actions/set_temperature", json={"extruder": 80})
    assert answer.status_code == 200, answer.text
    open_fleet(page, kybercore_server.url)
    tile(page, "fleet-c").locator("[data-action=files]").click()
    drawer = page.get_by_role("dialog", name="Printer C")
    graph = drawer.get_by_role("img", name="Temperatures, last 30 minutes")
    expect(graph.locator("canvas")).to_have_count(1)
    # uPlot came from beside charts.js: the page's versioned, long-cached prefix.
    assert (page.locator("script[src*=uPlot]").get_attribute("src") or "").startswith(
        f"{kybercore_server.url}/static/v-"
    )
    # The live values keep arriving: the graph grows and shows the target it heats to.
    start = int(graph.get_attribute("data-points") or 0)
    wait_until(lambda: int(graph.get_attribute("data-points") or 0) >= start + 2, what="growth")
    expect(graph).to_have_attribute("aria-label", re.compile(r"Hotend [\d.]+° \(target 80°\)"))
    assert nonblank_pixels(graph) > 500
    drawer.screenshot(path=str(ARTIFACTS / "temperatures.png"))
    drawer.get_by_role("button", name="Close").click()
    expect(graph).to_be_hidden()
