"""A printer's limits (max temperatures, volume, nozzle): read after every connect, retried
when the read fails, and never silently missing from an action's checks."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest

from kybercore.errors import ActionRejected
from kybercore.fleet.service import FleetService
from kybercore.fleet.sessions import FleetPrinter
from kybercore.registry.models import BuildVolume, Capabilities, PrinterConfig, PrinterCreate
from kybercore.registry.store import PrinterRegistry
from kybercore.sim.stack import PrinterStack
from tests.hardening.faulty_moonraker import FaultyMoonraker
from tests.helpers import wait_for

SETTINGS = {
    "stepper_x": {"position_max": 220.0},
    "stepper_y": {"position_max": 220.0},
    "stepper_z": {"position_max": 250.0},
    "extruder": {"nozzle_diameter": 0.4, "max_temp": 250.0},
    "heater_bed": {"max_temp": 110.0},
}
RETRIED_WITHIN = 10.0
"""Promise: a failed read is retried, the first time within LIMITS_RETRY_FIRST (1 s, with
jitter 0.5-1 s); the view then shows the limits within a hub tick. 10x slack."""


@pytest.fixture
async def fleet(tmp_path: Path, http: httpx.AsyncClient) -> AsyncIterator[FleetService]:
    service = FleetService(PrinterRegistry(tmp_path / "printers.json"), http)
    await service.start()
    try:
        yield service
    finally:
        await service.stop()


@pytest.fixture
async def standin() -> AsyncIterator[FaultyMoonraker]:
    """FAULT-INJECTION stand-in, not Moonraker: it answers the configfile query with an
    error until told the settings, which a real Klippy cannot be made to do on demand."""
    standin = FaultyMoonraker("healthy", interval=0.25)
    await standin.start()
    yield standin
    await standin.stop()


@pytest.fixture
async def second_standin() -> AsyncIterator[FaultyMoonraker]:
    """Another such stand-in: one Moonraker drives one printer."""
    standin = FaultyMoonraker("healthy", interval=0.25)
    await standin.start()
    yield standin
    await standin.stop()


async def test_a_failed_limits_read_refuses_what_needs_them_and_is_retried(
    fleet: FleetService, standin: FaultyMoonraker, second_standin: FaultyMoonraker
) -> None:
    await fleet.add_printer(PrinterCreate(id="p", name="P", moonraker_url=standin.url))
    given = Capabilities(
        build_volume=BuildVolume(x=200, y=200, z=200),
        nozzle_diameter=0.4,
        max_extruder_temp=260,
        max_bed_temp=100,
    )
    await fleet.add_printer(
        PrinterCreate(id="q", name="Q", moonraker_url=second_standin.url, capabilities=given)
    )
    await wait_for(lambda: fleet.view("p")["limits"] == "unknown", what="limits unknown")
    await wait_for(lambda: fleet.view("q")["klippy_state"] == "ready", what="q ready")

    verdict = await fleet.dry_run("p", "set_temperature", {"extruder": 200})
    assert [(r.code, r.level) for r in verdict.reasons] == [("limits_unknown", "block")]
    with pytest.raises(ActionRejected) as refused:
        await fleet.act("p", "gcode", {"script": "M104 S200"})
    assert refused.value.code == "limits_unknown"
    assert "printers.json" in refused.value.message
    view = fleet.view("p")
    assert not view["actions"]["set_temperature"]
    assert view["actions"]["emergency_stop"]
    assert (await fleet.dry_run("p", "emergency_stop")).level == "ok"
    # printers.json's own limits are enough.
    assert fleet.view("q")["limits"] == "known"
    assert (await fleet.dry_run("q", "set_temperature", {"extruder": 200})).level == "ok"

    reads = standin.methods.count("printer.objects.query")
    standin.configfile = SETTINGS
    await wait_for(
        lambda: fleet.view("p")["limits"] == "known", RETRIED_WITHIN, "limits read on retry"
    )
    assert standin.methods.count("printer.objects.query") > reads
    assert fleet.view("p")["capabilities"]["max_extruder_temp"] == 250
    assert (await fleet.dry_run("p", "set_temperature", {"extruder": 200})).level == "ok"
    too_hot = await fleet.dry_run("p", "set_temperature", {"extruder": 300})
    assert [r.code for r in too_hot.reasons] == ["extruder_temp_over_max"]


@pytest.mark.integration
async def test_an_action_right_after_connect_is_judged_against_the_limits(
    fleet: FleetService, printer: PrinterStack
) -> None:
    for attempt in range(5):
        pid = f"new-{attempt}"
        await fleet.add_printer(PrinterCreate(id=pid, name=pid, moonraker_url=printer.url))
        live = fleet.sessions.get(pid).live
        # The earliest moment an action can pass the state rules: Klippy shown ready.
        while live.klippy_state != "ready":
            await asyncio.sleep(0)
        verdict = await fleet.dry_run(pid, "set_temperature", {"extruder": 600})
        assert verdict.blocked
        assert [r.code for r in verdict.reasons] in (
            ["extruder_temp_over_max"],  # the read came within the wait
            ["limits_loading"],  # it did not: refused all the same
        )
        await fleet.remove_printer(pid)


async def test_an_action_waits_for_a_read_started_again_before_it_resumed() -> None:
    # A read finishes (the event set) and, before the waiting action resumes, a new
    # subscription snapshot starts another (the event cleared, the limits "loading" again):
    # the action must wait for that read too, not be refused with ``limits_loading``.
    printer = FleetPrinter(PrinterConfig(id="p", name="P", moonraker_url="http://x"), None)
    printer.live.connection = "online"
    waiting = asyncio.create_task(printer.wait_for_limits(RETRIED_WITHIN))
    await _turns()  # the action is now waiting
    printer.live.limits = "known"
    printer.limits_tried.set()
    printer.live.limits = "loading"
    printer.limits_tried.clear()
    await _turns()  # ample for the waiter to resume
    assert not waiting.done()
    printer.live.limits = "known"
    printer.limits_tried.set()
    await asyncio.wait_for(waiting, RETRIED_WITHIN)


async def _turns() -> None:
    """Let the event loop turn 20 times: a count of turns, not a time."""
    for _ in range(20):
        await asyncio.sleep(0)
