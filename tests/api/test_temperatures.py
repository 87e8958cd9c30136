"""``GET /api/printers/{id}/temperatures`` on a real printer: what it heats shows up."""

from __future__ import annotations

import time
from collections.abc import AsyncIterator

import httpx
import pytest

from tests.helpers import KyberCoreServer, wait_for

pytestmark = pytest.mark.integration


@pytest.fixture
async def api(kybercore_server: KyberCoreServer) -> AsyncIterator[httpx.AsyncClient]:
    async with httpx.AsyncClient(base_url=kybercore_server.url, timeout=60) as client:
        yield client


async def test_a_heating_printer_draws_its_curve(api: httpx.AsyncClient) -> None:
    path = "/api/printers/fleet-b/temperatures"
    asked = time.time()
    answer = await api.post("/api/printers/fleet-b/actions/set_temperature", json={"extruder": 60})
    assert answer.status_code == 200, answer.text
    try:

        async def heated() -> bool:
            # Heating to this target, past 50 °C: the hotend may still be warm from an
            # earlier test, so the temperature alone proves nothing.
            series = (await api.get(path)).json()["series"]["extruder"]
            pairs = zip(series["temperature"], series["target"], strict=True)
            return any(temp is not None and temp > 50 and aim == 60 for temp, aim in pairs)

        await wait_for(heated, timeout=60, what="the extruder's curve to pass 50 °C")
    finally:
        await api.post("/api/printers/fleet-b/actions/set_temperature", json={"extruder": 0})
    body = (await api.get(path, params={"minutes": 5})).json()
    assert body["printer"] == "fleet-b"
    extruder = body["series"]["extruder"]
    assert len(extruder["t"]) == len(extruder["temperature"]) == len(extruder["target"])
    assert extruder["t"] == sorted(extruder["t"])
    assert time.time() - 5 * 60 - 1 <= extruder["t"][0]
    assert extruder["t"][-1] <= time.time() + 1
    # At most one sample a second: the ring never holds Moonraker's four pushes a second.
    spacing = [b - a for a, b in zip(extruder["t"], extruder["t"][1:], strict=False)]
    assert all(step > 0 for step in spacing)
    assert len(extruder["t"]) <= (extruder["t"][-1] - extruder["t"][0]) + 2
    samples = list(zip(extruder["t"], extruder["temperature"], extruder["target"], strict=True))
    heating = [(temp, target) for t, temp, target in samples if t >= asked - 1]
    assert 60.0 in [target for _, target in heating]
    assert max(temp for temp, _ in heating if temp is not None) > 50
    assert "heater_bed" in body["series"]


async def test_unknown_printer_and_bad_window_are_refused(api: httpx.AsyncClient) -> None:
    missing = await api.get("/api/printers/nope/temperatures")
    assert missing.status_code == 404
    assert missing.json()["error"]["code"] == "unknown_printer"
    for minutes in ("0", "31", "x"):
        bad = await api.get("/api/printers/fleet-a/temperatures", params={"minutes": minutes})
        assert bad.status_code == 422, minutes
