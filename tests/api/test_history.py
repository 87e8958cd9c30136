"""The ledger's HTTP face on a real `kybercore serve` over real printers: the job history
(paged, filtered, as CSV) and the statistics, for viewers only once tokens exist."""

from __future__ import annotations

import csv
import io
import uuid
from collections.abc import AsyncIterator

import httpx
import pytest

from kybercore.ledger.records import COLUMNS
from tests.api.conftest import StartEdge
from tests.helpers import KyberCoreServer, travel_gcode, wait_for

pytestmark = pytest.mark.integration

PRINTED_WITHIN = 120.0
"""Upload, homing and 2 s of moves: ~5 s on an idle machine."""
ROW_FIELDS = set(COLUMNS)


@pytest.fixture
async def api(kybercore_server: KyberCoreServer) -> AsyncIterator[httpx.AsyncClient]:
    async with httpx.AsyncClient(base_url=kybercore_server.url, timeout=60) as client:
        yield client


@pytest.fixture
async def printed(api: httpx.AsyncClient) -> str:
    """A print just run to completion on fleet-b through the API; its file name."""
    name = f"history-{uuid.uuid4().hex[:8]}.gcode"
    files = {"file": (name, travel_gcode(moves=4, feedrate=6000))}
    answer = await api.post("/api/printers/fleet-b/files", files=files, data={"start": "true"})
    assert answer.status_code == 201, answer.text

    async def recorded() -> bool:
        items = (await api.get("/api/history", params={"file": name})).json()["items"]
        return bool(items) and items[0]["status"] == "completed"

    await wait_for(recorded, PRINTED_WITHIN, f"{name} completed in the history")
    return name


async def test_the_history_lists_a_print_with_its_fields_and_filters(
    api: httpx.AsyncClient, printed: str
) -> None:
    page = (await api.get("/api/history", params={"file": printed})).json()
    assert page["total"] == 1
    row = page["items"][0]
    assert set(row) == ROW_FIELDS
    assert (row["printer"], row["filename"], row["status"]) == ("fleet-b", printed, "completed")
    assert row["started_at"].endswith("Z")
    assert row["started_at"] <= row["ended_at"]
    # Klipper counts print time from the first extrusion: a travel-only file has none.
    assert (row["print_seconds"], row["filament_mm"], row["filament_g"]) == (0.0, 0.0, None)
    assert (row["sha256"], row["job_id"], row["attempt_id"]) == (None, None, None)

    for params, matches in (
        ({"printer": "fleet-b"}, True),
        ({"printer": "fleet-a"}, False),
        ({"status": "completed"}, True),
        ({"status": "cancelled"}, False),
        ({"file": printed.upper()}, True),
        ({"to": row["started_at"]}, False),  # `to` is exclusive
        ({"from": row["started_at"]}, True),
    ):
        found = (await api.get("/api/history", params={"file": printed, **params})).json()
        assert found["total"] == int(matches), params


async def test_pages_cover_the_history_once_newest_first(
    api: httpx.AsyncClient, printed: str
) -> None:
    total = (await api.get("/api/history", params={"limit": 1})).json()["total"]
    assert total >= 1
    seen: list[tuple[str, str]] = []
    starts: list[str] = []
    for offset in range(0, total, 2):
        items = (await api.get("/api/history", params={"limit": 2, "offset": offset})).json()[
            "items"
        ]
        seen += [(r["printer"], r["moonraker_job_id"]) for r in items]
        starts += [r["started_at"] for r in items]
    assert len(seen) == len(set(seen)) == total
    assert starts == sorted(starts, reverse=True)


async def test_the_csv_has_a_header_and_one_row_per_job(
    api: httpx.AsyncClient, printed: str
) -> None:
    answer = await api.get("/api/history.csv", params={"printer": "fleet-b"})
    assert answer.status_code == 200
    assert answer.headers["content-type"].startswith("text/csv")
    assert "attachment" in answer.headers["content-disposition"]
    table = list(csv.reader(io.StringIO(answer.text)))
    assert tuple(table[0]) == COLUMNS
    total = (await api.get("/api/history", params={"printer": "fleet-b"})).json()["total"]
    assert len(table) - 1 == total
    mine = [dict(zip(COLUMNS, r, strict=True)) for r in table[1:] if r[2] == printed]
    assert len(mine) == 1
    assert (mine[0]["status"], mine[0]["sha256"], mine[0]["verdict"]) == ("completed", "", "")


async def test_statistics_per_printer_and_per_day(api: httpx.AsyncClient, printed: str) -> None:
    answer = (await api.get("/api/stats", params={"group_by": "printer"})).json()
    assert answer["group_by"] == "printer"
    assert answer["from"] < answer["to"]
    rows = {row["key"]: row for row in answer["rows"]}
    assert {"fleet-a", "fleet-b", "fleet-c"} <= set(rows)
    b = rows["fleet-b"]
    assert b["jobs"]["completed"] >= 1
    assert 0 < b["success_rate"] <= 1
    # The server has watched fleet-b for a while, printing part of it.
    assert b["utilisation"] is not None
    assert 0 < b["utilisation"] <= 1
    days = (await api.get("/api/stats", params={"group_by": "day"})).json()["rows"]
    assert len(days) in (30, 31)  # the default window: the last 30 days, partial days included
    assert sum(d["jobs"].get("completed", 0) for d in days) >= 1
    material = (await api.get("/api/stats", params={"group_by": "material"})).json()["rows"]
    assert "PLA" in {row["key"] for row in material}  # travel_gcode says filament_type = PLA


async def test_bad_queries_are_refused_with_the_reason(api: httpx.AsyncClient) -> None:
    for path, params in (
        ("/api/history", {"limit": 0}),
        ("/api/history", {"limit": 501}),
        ("/api/history", {"offset": -1}),
        ("/api/history", {"from": "yesterday"}),
        ("/api/stats", {"group_by": "colour"}),
        ("/api/stats", {"from": "2026-02-01T00:00:00Z", "to": "2026-01-01T00:00:00Z"}),
        ("/api/stats", {"group_by": "day", "from": "2000-01-01T00:00:00Z"}),
    ):
        answer = await api.get(path, params=params)
        assert answer.status_code == 422, (path, params, answer.text)
        assert answer.json()["error"]["message"], (path, params)


async def test_history_and_stats_need_a_viewer_token_once_tokens_exist(
    edge_server: StartEdge,
) -> None:
    server, admin = edge_server(tokens=True)
    async with httpx.AsyncClient(base_url=server.url, timeout=30) as client:
        for path in ("/api/history", "/api/history.csv", "/api/stats"):
            assert (await client.get(path)).status_code == 401, path
            answer = await client.get(path, headers={"Authorization": f"Bearer {admin}"})
            assert answer.status_code == 200, path
        empty = (
            await client.get("/api/history", headers={"Authorization": f"Bearer {admin}"})
        ).json()
        assert empty == {"total": 0, "items": []}
