"""An upload with ``start`` answers what happened: the file stored, and the start done or
refused with its reason, so scripts never upload again a file that is already there. Real
Moonraker + Klippy behind a real ``kybercore serve``."""

from __future__ import annotations

import uuid
from collections.abc import AsyncIterator

import httpx
import pytest

from tests.helpers import KyberCoreServer, travel_gcode

pytestmark = pytest.mark.integration


@pytest.fixture
async def api(kybercore_server: KyberCoreServer) -> AsyncIterator[httpx.AsyncClient]:
    async with httpx.AsyncClient(base_url=kybercore_server.url, timeout=60) as client:
        yield client


async def listed(api: httpx.AsyncClient, printer: str, name: str) -> bool:
    files = (await api.get(f"/api/printers/{printer}/files")).json()
    return name in [f["path"] for f in files]


async def test_a_refused_start_after_an_upload_says_the_file_is_stored(
    api: httpx.AsyncClient,
) -> None:
    # fleet-c has a 0.6 mm nozzle; the file was sliced for 0.4 mm: stored, never started.
    name = f"partial-{uuid.uuid4().hex[:6]}.gcode"
    answer = await api.post(
        "/api/printers/fleet-c/files",
        files={"file": (name, travel_gcode())},
        data={"start": "true"},
    )
    try:
        assert answer.status_code == 201, answer.text
        body = answer.json()
        assert (body["action"], body["ok"], body["uploaded"], body["started"]) == (
            "upload",
            True,
            True,
            False,
        )
        start = body["start"]
        assert (start["action"], start["ok"], start["status"]) == ("start", False, 422)
        assert "nozzle_mismatch" in [r["code"] for r in start["reasons"]]
        assert "nozzle_mismatch" in [r["code"] for r in body["reasons"]]
        assert "Uploaded" in body["message"]
        assert "not started" in body["message"].lower()
        assert await listed(api, "fleet-c", name)
        view = (await api.get("/api/printers/fleet-c")).json()
        assert view["job"]["state"] != "printing"
    finally:
        await api.delete("/api/printers/fleet-c/files", params={"path": name})


async def test_an_upload_that_starts_says_both(api: httpx.AsyncClient) -> None:
    name = f"started-{uuid.uuid4().hex[:6]}.gcode"
    answer = await api.post(
        "/api/printers/fleet-a/files",
        files={"file": (name, travel_gcode())},
        data={"start": "true"},
    )
    try:
        assert answer.status_code == 201, answer.text
        body = answer.json()
        assert (body["uploaded"], body["started"], body["start"]["ok"]) == (True, True, True)
        assert (await api.get("/api/printers/fleet-a")).json()["job"]["state"] == "printing"
    finally:
        await api.post("/api/printers/fleet-a/actions/cancel")
    plain = await api.post(
        "/api/printers/fleet-a/files", files={"file": (f"plain-{name}", travel_gcode())}
    )
    assert plain.status_code == 201, plain.text
    assert (plain.json()["uploaded"], plain.json()["started"]) == (True, None)
