"""A request the printer refuses answers 404/409/422 in Klipper's own words, never 502:
a real `kybercore serve` over a real Moonraker + Klippy printer of this test's own."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable

import httpx
import pytest

from kybercore.sim.stack import PrinterStack
from tests.helpers import KyberCoreServer, wait_for

pytestmark = pytest.mark.integration


@pytest.fixture
async def refusing(
    kybercore_server: KyberCoreServer, start_stack: Callable[..., PrinterStack]
) -> AsyncIterator[httpx.AsyncClient]:
    """The API, with a printer `refusing` of this test's own (it will be e-stopped)."""
    stack = start_stack("refusing")
    async with httpx.AsyncClient(base_url=kybercore_server.url, timeout=60) as api:
        added = await api.post(
            "/api/printers", json={"id": "refusing", "name": "R", "moonraker_url": stack.url}
        )
        assert added.status_code == 201, added.text
        try:
            await wait_for(lambda: klippy(api, "ready"), timeout=30, what="the new printer ready")
            yield api
        finally:
            assert (await api.delete("/api/printers/refusing")).status_code == 204
            stack.stop()


async def klippy(api: httpx.AsyncClient, state: str) -> bool:
    view = (await api.get("/api/printers/refusing")).json()
    # Limits known too: an action sooner waits for them (LIMITS_WAIT), not this test's subject.
    return bool(
        view["connection"] == "online"
        and view["klippy_state"] == state
        and (state != "ready" or view["limits"] == "known")
    )


async def gcode(api: httpx.AsyncClient, script: str) -> httpx.Response:
    return await api.post("/api/printers/refusing/gcode", json={"script": script})


async def test_the_printers_refusals_in_its_own_words(refusing: httpx.AsyncClient) -> None:
    api = refusing
    missing = await api.delete("/api/printers/refusing/files", params={"path": "nonexistent.gcode"})
    assert missing.status_code == 404, missing.text
    assert "Invalid file path" in missing.json()["error"]["message"]

    unhomed = await gcode(api, "G1 Z5")
    assert unhomed.status_code == 409, unhomed.text
    assert unhomed.json()["error"]["code"] == "klipper_refused"
    assert "Must home axis first" in unhomed.json()["error"]["message"]

    stop = await api.post("/api/printers/refusing/actions/emergency_stop")
    assert stop.status_code == 200, stop.text
    await wait_for(lambda: klippy(api, "shutdown"), what="Klippy shown shut down")
    status = await gcode(api, "STATUS")
    assert status.status_code == 409, status.text
    message = status.json()["error"]["message"]
    assert "Shutdown due to webhooks request" in message
    assert "Unknown" not in message
