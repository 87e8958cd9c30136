"""What an action's answer promises is what KyberCore knows and shows at once: start, pause,
resume and cancel sent back to back with no wait each succeed, over REST and in bulk, and a
GET right after each answer shows the new state. Real Moonraker + Klippy behind a real
``kybercore serve`` (Moonraker driven directly accepts the same sequence)."""

from __future__ import annotations

import uuid
from collections.abc import AsyncIterator

import httpx
import pytest

from tests.helpers import KyberCoreServer, travel_gcode

pytestmark = pytest.mark.integration

SEQUENCE = (
    ("start", "printing"),
    ("pause", "paused"),
    ("resume", "printing"),
    ("cancel", "cancelled"),
)


@pytest.fixture
async def api(kybercore_server: KyberCoreServer) -> AsyncIterator[httpx.AsyncClient]:
    async with httpx.AsyncClient(base_url=kybercore_server.url, timeout=60) as client:
        yield client


async def upload(api: httpx.AsyncClient, *printers: str) -> str:
    name = f"b2b-{uuid.uuid4().hex[:6]}.gcode"
    for printer in printers:
        answer = await api.post(
            f"/api/printers/{printer}/files", files={"file": (name, travel_gcode(moves=40))}
        )
        assert answer.status_code == 201, answer.text
    return name


async def shown(api: httpx.AsyncClient, printer: str) -> str:
    return str((await api.get(f"/api/printers/{printer}")).json()["job"]["state"])


async def test_back_to_back_actions_over_rest(api: httpx.AsyncClient) -> None:
    name = await upload(api, "fleet-a")
    for action, state in SEQUENCE:
        body = {"filename": name} if action == "start" else {}
        answer = await api.post(f"/api/printers/fleet-a/actions/{action}", json=body)
        assert answer.status_code == 200, (action, answer.text)
        assert answer.json()["ok"]
        assert await shown(api, "fleet-a") == state, action
        fleet = (await api.get("/api/printers")).json()
        assert next(v for v in fleet if v["id"] == "fleet-a")["job"]["state"] == state, action


async def test_back_to_back_actions_in_bulk(api: httpx.AsyncClient) -> None:
    printers = ["fleet-a", "fleet-b"]
    name = await upload(api, *printers)
    for action, state in SEQUENCE:
        body: dict[str, object] = {"printer_ids": printers}
        if action == "start":
            body["filename"] = name
        answer = await api.post(f"/api/fleet/actions/{action}", json=body)
        assert answer.status_code == 200, answer.text
        results = answer.json()["results"]
        assert [(r["printer_id"], r["ok"]) for r in results] == [(p, True) for p in printers], (
            action,
            results,
        )
        for printer in printers:
            assert await shown(api, printer) == state, (action, printer)
