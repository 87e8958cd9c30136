"""After an emergency stop only a firmware restart brings Klippy back, and KyberCore says so
before a Klipper restart leaves the printer in error. Real Moonraker + Klippy."""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest

from kybercore.errors import ActionRejected
from kybercore.fleet.service import FleetService
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import PrinterRegistry, write_printers
from kybercore.sim.stack import PrinterStack
from tests.helpers import wait_for

pytestmark = pytest.mark.integration


@pytest.fixture
async def fleet(
    own_printer: PrinterStack, tmp_path: Path, http: httpx.AsyncClient
) -> AsyncIterator[FleetService]:
    path = tmp_path / "printers.json"
    write_printers(path, [PrinterConfig(id="p", name="P", moonraker_url=own_printer.url)])
    service = FleetService(PrinterRegistry(path), http)
    await service.start()
    try:
        await wait_for(lambda: service.view("p")["klippy_state"] == "ready", what="ready")
        yield service
    finally:
        await service.stop()


async def test_after_an_emergency_stop_the_check_steers_to_a_firmware_restart(
    fleet: FleetService, own_printer: PrinterStack, http: httpx.AsyncClient
) -> None:
    await fleet.act("p", "emergency_stop")
    await wait_for(lambda: fleet.view("p")["klippy_state"] == "shutdown", what="shutdown")

    verdict = await fleet.dry_run("p", "restart")
    assert [(r.code, r.level) for r in verdict.reasons] == [("restart_after_shutdown", "block")]
    assert "firmware restart" in verdict.reasons[0].en
    assert not fleet.view("p")["actions"]["restart"]
    with pytest.raises(ActionRejected) as refused:
        await fleet.act("p", "restart")
    assert refused.value.code == "restart_after_shutdown"
    assert (await fleet.dry_run("p", "firmware_restart")).level == "ok"

    # What the rule prevents, sent straight to Moonraker: the restart leaves Klippy in error.
    (await http.post(f"{own_printer.url}/printer/restart")).raise_for_status()

    async def klippy() -> dict[str, str]:
        info = (await http.get(f"{own_printer.url}/printer/info")).json()["result"]
        return {"state": info["state"], "message": info["state_message"]}

    async def in_error() -> bool:
        try:
            return (await klippy())["state"] == "error"
        except (httpx.HTTPError, KeyError):
            return False  # Klippy is restarting: /printer/info is not there for a moment

    await wait_for(in_error, what="Klippy in error after the restart")
    assert "config as it is shutdown" in (await klippy())["message"]

    await wait_for(lambda: fleet.view("p")["klippy_state"] == "error", what="error shown")

    # The way KyberCore pointed to works.
    await fleet.act("p", "firmware_restart")
    await wait_for(lambda: fleet.view("p")["klippy_state"] == "ready", 30, "ready again")
