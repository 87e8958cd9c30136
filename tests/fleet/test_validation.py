"""Validation through the real stack: Moonraker parses the slicer files, KyberCore judges
each printer of a mixed fleet, and the real action then does what the dry run said."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest
from pydantic import SecretStr

from kybercore.fleet.advisor import AdvisorConfig
from kybercore.fleet.service import FleetService
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import PrinterRegistry, write_printers
from kybercore.sim.stack import PrinterStack
from tests.fleet.test_advisor import FakeChatCompletionsServer
from tests.helpers import KyberCoreServer, wait_for

pytestmark = pytest.mark.integration

SAMPLES = Path(__file__).parents[1] / "samples" / "gcode"
TALL = "cura_tall_300mm_pla.gcode"  # object height 300 mm, 0.4 mm nozzle
CUBE = "cura_cube_20mm_pla.gcode"  # 20 mm, 0.4 mm nozzle
FLEET = ["fleet-a", "fleet-b", "fleet-c"]  # Z 250 / 400 / 180 mm; nozzle 0.4 / 0.4 / 0.6
ADVISOR_CUT_WITHIN = 5.0
"""Promise: a dry run waits for the advisor no longer than its budget (1.0 s here). Idle:
1.00 s (5x; the test prints it)."""


@pytest.fixture
async def api(kybercore_server: KyberCoreServer) -> AsyncIterator[httpx.AsyncClient]:
    async with httpx.AsyncClient(base_url=kybercore_server.url, timeout=60) as client:
        for printer in FLEET:
            for name in (TALL, CUBE):
                files = {"file": (name, (SAMPLES / name).read_bytes())}
                answer = await client.post(f"/api/printers/{printer}/files", files=files)
                assert answer.status_code == 201, answer.text
        yield client


async def _wait_state(api: httpx.AsyncClient, printer: str, state: str) -> None:
    for _ in range(300):
        if (await api.get(f"/api/printers/{printer}")).json()["job"]["state"] == state:
            return
        await asyncio.sleep(0.05)  # poll: wait for the job state, 300 tries
    raise AssertionError(f"{printer} never reached {state}")


async def test_a_file_too_tall_for_one_printer_prints_on_a_taller_one(
    api: httpx.AsyncClient,
) -> None:
    refused = await api.post("/api/printers/fleet-a/actions/start", json={"filename": TALL})
    assert refused.status_code == 422
    error = refused.json()["error"]
    assert [r["code"] for r in error["reasons"] if r["level"] == "block"] == ["file_too_tall"]
    assert "300" in error["message"]
    assert (await api.get("/api/printers/fleet-a")).json()["job"]["state"] != "printing"

    accepted = await api.post("/api/printers/fleet-b/actions/start", json={"filename": TALL})
    assert accepted.status_code == 200, accepted.text
    await _wait_state(api, "fleet-b", "printing")
    cancelled = await api.post("/api/printers/fleet-b/actions/cancel")
    assert cancelled.status_code == 200
    await _wait_state(api, "fleet-b", "cancelled")


async def test_the_dry_run_over_a_mixed_fleet_says_what_the_action_then_does(
    api: httpx.AsyncClient,
) -> None:
    body = {"printer_ids": FLEET, "filename": CUBE}
    checks = (await api.post("/api/fleet/actions/start/check", json=body)).json()["results"]
    levels = {c["printer_id"]: c["level"] for c in checks}
    assert levels == {"fleet-a": "ok", "fleet-b": "ok", "fleet-c": "block"}
    blocked = next(c for c in checks if c["printer_id"] == "fleet-c")
    assert [r["code"] for r in blocked["reasons"]] == ["nozzle_mismatch"]
    # The dry run changed nothing.
    for printer in FLEET:
        assert (await api.get(f"/api/printers/{printer}")).json()["job"]["state"] != "printing"

    results = (await api.post("/api/fleet/actions/start", json=body)).json()["results"]
    outcomes = {r["printer_id"]: (r["ok"], r["status"]) for r in results}
    assert outcomes == {"fleet-a": (True, 200), "fleet-b": (True, 200), "fleet-c": (False, 422)}
    for printer, (ok, _status) in outcomes.items():
        if ok:
            await _wait_state(api, printer, "printing")
    cancel = {"printer_ids": ["fleet-a", "fleet-b"]}
    results = (await api.post("/api/fleet/actions/cancel", json=cancel)).json()["results"]
    assert [r["ok"] for r in results] == [True, True]
    for printer in ("fleet-a", "fleet-b"):
        await _wait_state(api, printer, "cancelled")


@pytest.fixture
async def advised_fleet(
    fleet_stacks: list[PrinterStack], tmp_path: Path, http: httpx.AsyncClient
) -> AsyncIterator[tuple[FleetService, FakeChatCompletionsServer]]:
    """A FleetService with one real printer and the advisor stand-in (not a real model)."""
    path = tmp_path / "printers.json"
    stack = fleet_stacks[1]
    write_printers(path, [PrinterConfig(id="b", name="B", moonraker_url=stack.url)])
    async with FakeChatCompletionsServer(mode="warnings", stall_seconds=60) as advisor:
        config = AdvisorConfig(advisor.url, SecretStr("advisor-key"), budget_seconds=1.0)
        service = FleetService(PrinterRegistry(path), http, advisor=config)
        await service.start()
        try:
            await wait_for(
                lambda: service.view("b")["klippy_state"] == "ready", what="printer ready"
            )
            yield service, advisor
        finally:
            await service.stop()


async def test_the_advisor_adds_warnings_and_is_cut_at_its_budget(
    advised_fleet: tuple[FleetService, FakeChatCompletionsServer],
) -> None:
    service, advisor = advised_fleet
    verdict = await service.dry_run("b", "set_temperature", {"extruder": 200})
    assert verdict.level == "warn"
    assert {r.code for r in verdict.reasons} == {"advisor_warning"}
    assert advisor.requests[-1].headers["authorization"] == "Bearer advisor-key"

    advisor.mode = "stall"  # for 60 s, far beyond the bound: only a cut ends the wait
    started = time.monotonic()
    verdict = await service.dry_run("b", "set_temperature", {"extruder": 200})
    cut_after = time.monotonic() - started
    print(f"\nthe stalled advisor was cut after {cut_after:.2f} s")
    assert cut_after < ADVISOR_CUT_WITHIN
    assert [r.code for r in verdict.reasons] == ["advisor_unavailable"]

    # Blocks come from the rules alone: the advisor is not even asked.
    asked = len(advisor.requests)
    blocked = await service.dry_run("b", "set_temperature", {"extruder": 999})
    assert blocked.blocked
    assert len(advisor.requests) == asked
