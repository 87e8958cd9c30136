"""The job queue's printers on a front (FrontPrinters), against real processes: a
nats-server, two ingest workers and real virtual printers, with a FrontFleet in this test's
process. What the queue plans from is what the printers' own Moonraker says; a file
uploaded and started through the owners prints, its start is heard, it cancels, and its
job is found in Moonraker's history by its upload name."""

from __future__ import annotations

import uuid
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from kybercore.core.validation import PrinterFacts
from kybercore.core.view import detect_capabilities
from kybercore.db import default_database_url, open_database
from kybercore.jobs.printers import Change
from kybercore.jobs.store import JobStore
from kybercore.jobs.tracker import Tracker
from kybercore.scale.front import FrontFleet
from kybercore.scale.queue import FrontPrinters
from kybercore.sim.stack import PrinterStack
from tests.helpers import travel_gcode, wait_for
from tests.jobs.conftest import new_job
from tests.scale.cluster import SLOTS, Cluster

pytestmark = pytest.mark.integration

PRINTS_WITHIN = 30.0
"""A start reaches print_stats "printing" (about a second on an idle machine)."""


@pytest.fixture
async def front(cluster: Cluster) -> AsyncIterator[FrontFleet]:
    """A front in this process, on the cluster's broker, once it shows every printer fresh."""
    async with httpx.AsyncClient() as http:
        fleet = FrontFleet(
            cluster.broker.url, http, slots=SLOTS, printers_file=cluster.folder / "printers.json"
        )
        await fleet.start()
        try:
            printers = FrontPrinters(fleet)

            def fresh() -> bool:
                shown = [printers.shown(c.id) for c in fleet.configs()]
                return len(shown) == 3 and all(
                    (s.connection, s.klippy_state) == ("online", "ready") for s in shown
                )

            await wait_for(fresh, 30, "every printer fresh on the test's front")
            yield fleet
        finally:
            await fleet.stop()


async def moonraker(stack: PrinterStack, path: str, **params: Any) -> Any:
    """What the printer's own Moonraker answers (``result``)."""
    async with httpx.AsyncClient(timeout=30) as client:
        answer = await client.get(f"{stack.url}{path}", params=params)
    answer.raise_for_status()
    return answer.json()["result"]


async def expected_facts(stack: PrinterStack) -> PrinterFacts:
    """Validation's facts as worked out from the printer's own Moonraker and Klipper."""
    query = {"configfile": "settings", "toolhead": "axis_minimum", "print_stats": "state"}
    status = (await moonraker(stack, "/printer/objects/query", **query))["status"]
    caps = detect_capabilities(status["configfile"]["settings"])
    volume = caps["build_volume"]
    return PrinterFacts(
        connection="online",
        klippy_state="ready",
        print_state=status["print_stats"]["state"],
        model="Virtual",
        build_volume=(volume["x"], volume["y"], volume["z"]),
        axis_minimum=tuple(status["toolhead"]["axis_minimum"][:3]),
        nozzle_diameter=caps["nozzle_diameter"],
        max_extruder_temp=caps["max_extruder_temp"],
        max_bed_temp=caps["max_bed_temp"],
        limits="known",
    )


async def test_every_printer_is_planned_from_what_its_moonraker_says(
    front: FrontFleet, fleet_stacks: list[PrinterStack]
) -> None:
    found = {p.config.id: p for p in FrontPrinters(front).all()}
    assert set(found) == {s.options.name for s in fleet_stacks}
    for stack in fleet_stacks:
        printer = found[stack.options.name]
        assert printer.facts == await expected_facts(stack), stack.options.name
    assert found["fleet-c"].facts.build_volume == (180.0, 180.0, 180.0)
    assert found["fleet-c"].facts.nozzle_diameter == 0.6


async def test_a_file_uploaded_and_started_through_the_owner_prints_and_cancels(
    front: FrontFleet, fleet_stacks: list[PrinterStack], tmp_path: Path
) -> None:
    printers = FrontPrinters(front)
    printer = "fleet-a"
    stack = next(s for s in fleet_stacks if s.options.name == printer)
    await wait_for(
        lambda: printers.shown(printer).state not in ("printing", "paused"), 30, "fleet-a idle"
    )
    name = f"kybercore/front-{uuid.uuid4().hex[:8]}.gcode"
    source = tmp_path / "part.gcode"
    source.write_bytes(travel_gcode())
    heard: list[tuple[str, Change]] = []
    stop = printers.listen(lambda printer_id, change: heard.append((printer_id, change)))
    try:
        await printers.upload(printer, name, source)
        listed = await moonraker(stack, "/server/files/list", root="gcodes")
        assert name in [f["path"] for f in listed]
        assert printers.shown(printer).state != "printing"  # uploaded, not started

        heard.clear()
        await printers.start(printer, name)

        def printing() -> bool:
            shown = printers.shown(printer)
            return (shown.state, shown.filename) == ("printing", name)

        await wait_for(printing, PRINTS_WITHIN, "the front's view of fleet-a printing the file")
        assert (printer, "state") in heard

        job = await printers.history_job(printer, name, None)
        assert job is not None
        assert (job["filename"], job["status"]) == (name, "in_progress")
        by_id = await printers.history_job(printer, name, str(job["job_id"]))
        assert by_id is not None
        assert by_id["job_id"] == job["job_id"]
        assert (
            await printers.history_job(printer, f"kybercore/none-{uuid.uuid4().hex}", None) is None
        )

        await printers.cancel(printer)
        await wait_for(
            lambda: printers.shown(printer).state == "cancelled", 30, "fleet-a cancelled"
        )

        async def recorded() -> bool:
            ended = await printers.history_job(printer, name, str(job["job_id"]))
            return ended is not None and ended["status"] == "cancelled"

        await wait_for(recorded, 30, "Moonraker's history recording the cancel")
    finally:
        stop()
        await leave_idle(front, printer, name)


async def leave_idle(front: FrontFleet, printer: str, name: str) -> None:
    """Leave the shared printer as the other tests expect it: idle, the file forgotten."""
    shown = FrontPrinters(front).shown(printer)
    if shown.state in ("printing", "paused"):
        await FrontPrinters(front).cancel(printer)
        await wait_for(
            lambda: FrontPrinters(front).shown(printer).state not in ("printing", "paused"),
            30,
            "fleet-a no longer printing",
        )
    await front.act(printer, "gcode", {"script": "SDCARD_RESET_FILE"})
    await front.delete_file(printer, name)


async def test_a_print_klipper_shut_down_is_recorded_with_klippys_message(
    front: FrontFleet, fleet_stacks: list[PrinterStack], tmp_path: Path
) -> None:
    # What the tracker has on a front when Klippy shuts down mid-print: the view blanks the
    # job's state while Klippy is not ready, Moonraker's history tells how it ended, and the
    # view's Klippy message says why, in the words `kybercore serve` records
    # (tests/jobs/test_outcomes.py).
    printers = FrontPrinters(front)
    printer = "fleet-c"
    engine = await open_database(default_database_url(tmp_path))
    store = JobStore(engine)
    job = await store.create_job(new_job(name=f"front-{uuid.uuid4().hex[:8]}.gcode"), "ana")
    attempt = await store.reserve(job.id, printer)
    assert attempt is not None
    name = attempt.upload_name
    tracker = Tracker(printers, store, on_ended=lambda: None)
    source = tmp_path / "part.gcode"
    source.write_bytes(travel_gcode())
    try:
        await printers.upload(printer, name, source)
        await printers.start(printer, name)
        await wait_for(
            lambda: printers.shown(printer).state == "printing", PRINTS_WITHIN, "printing"
        )
        # As the dispatcher hands a started print to the tracker.
        await store.advance(attempt.id, "printing")
        await tracker.start()
        await front.act(printer, "emergency_stop")
        # Klippy's state and its message may reach the front in two patches.
        await wait_for(
            lambda: (
                printers.shown(printer).klippy_state == "shutdown"
                and bool(printers.shown(printer).klippy_message)
            ),
            30,
            "Klippy shut down, with its message",
        )
        shown = printers.shown(printer)
        assert (shown.filename, shown.state) == (name, "")

        async def recorded() -> bool:
            job = await printers.history_job(printer, name, None)
            return job is not None and job["status"] == "klippy_shutdown"

        await wait_for(recorded, 30, "Moonraker's history recording the shutdown")

        async def ended() -> bool:
            return not (await store.attempt(attempt.id)).live

        await wait_for(ended, 30, "the tracker ending the attempt")
        failed = await store.attempt(attempt.id)
        why = shown.klippy_message.strip().splitlines()[0]
        assert (failed.state, failed.reason) == ("failed", f"Klipper shut down mid-print: {why}")
        assert failed.moonraker_job_id
    finally:
        await tracker.stop()
        await engine.dispose()
        if printers.shown(printer).klippy_state != "ready":
            await front.act(printer, "firmware_restart")
            await wait_for(
                lambda: printers.shown(printer).klippy_state == "ready", 60, "ready again"
            )
        await front.delete_file(printer, name)
