"""Verified starts: a printer that says yes to a start and never prints is caught, held with
the reason, and the copy goes to another printer; after ``max_attempts`` such failures the
job is blocked with the reason.

The printer that refuses is a FAULT-INJECTION stand-in (:mod:`tests.jobs.start_faults`) in
front of a real Moonraker + Klippy: everything but the start is real. The printer that
prints is a real virtual printer.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from pathlib import Path

import httpx
import pytest

from kybercore.db import default_database_url
from kybercore.sim.stack import PrinterStack
from tests.helpers import travel_gcode, wait_for
from tests.jobs.live_queue import live_queue, printer_config
from tests.jobs.start_faults import SWALLOWING, StartFaultProxy

pytestmark = pytest.mark.integration

START_WITHIN = 10.0
"""A real start shows ``printing`` within a second; ten is the bound the queue gives."""
SETTLE_TIMEOUT = 120.0
"""Two failed starts (START_WITHIN each) and a real print of ~10 s, with slack."""


@pytest.fixture(scope="module")
def behind_standins(start_stack: Callable[..., PrinterStack]) -> PrinterStack:
    """The real printer the stand-ins sit in front of; it never prints (starts are eaten)."""
    return start_stack("q-refuses")


@pytest.fixture(scope="module")
def good_printer(start_stack: Callable[..., PrinterStack]) -> PrinterStack:
    """A printer that starts what it is told to."""
    return start_stack("q-starts")


@pytest.fixture
async def standin() -> AsyncIterator[Callable[..., StartFaultProxy]]:
    """Start FAULT-INJECTION stand-ins in front of a real Moonraker; stopped after the test."""
    started: list[StartFaultProxy] = []

    async def start(upstream: PrinterStack, scenario: str) -> StartFaultProxy:
        proxy = StartFaultProxy(upstream.url, scenario)
        await proxy.start()
        started.append(proxy)
        return proxy

    yield start  # type: ignore[misc]
    for proxy in started:
        await proxy.stop()


@pytest.mark.parametrize("scenario", SWALLOWING)
async def test_a_start_accepted_but_never_seen_is_retried_on_another_printer(
    scenario: str,
    behind_standins: PrinterStack,
    good_printer: PrinterStack,
    standin: Callable[..., object],
    tmp_path: Path,
    http: httpx.AsyncClient,
) -> None:
    proxy = await standin(behind_standins, scenario)  # type: ignore[misc]
    # Ids rank the printers when nothing else does: "a-refuses" is tried first.
    printers = [
        printer_config(behind_standins, "a-refuses").model_copy(
            update={"moonraker_url": proxy.url}
        ),
        printer_config(good_printer, "b-starts"),
    ]
    async with live_queue(
        printers, tmp_path, http, default_database_url(tmp_path), start_within=START_WITHIN
    ) as live:
        job = await live.queue.add_job(
            "part.gcode", travel_gcode(moves=4, feedrate=6000), max_attempts=3, user="alice"
        )

        async def completed_elsewhere() -> bool:
            attempts = await live.attempts(job.id)
            return len(attempts) == 2 and attempts[1].state == "completed"

        await wait_for(completed_elsewhere, SETTLE_TIMEOUT, "the copy completed on b-starts")
        first, second = await live.attempts(job.id)
        assert (first.printer, first.state) == ("a-refuses", "failed_to_start")
        assert "accepted the start but was not printing" in first.reason
        assert proxy.starts_swallowed == [first.upload_name]
        assert (second.printer, second.copy) == ("b-starts", first.copy)

        held = await live.gate("a-refuses")
        assert held.state == "held"
        assert held.reason == first.reason or first.reason in held.reason
        stored = await live.job(job.id)
        assert (stored.state, stored.failures) == ("queued", 1)
        # The refusing printer's Klippy never printed anything of ours.
        assert not str(live.print_stats("a-refuses").get("filename", "")).startswith("kybercore/")


async def test_after_max_attempts_of_refused_starts_the_job_is_blocked_with_the_reason(
    behind_standins: PrinterStack,
    standin: Callable[..., object],
    tmp_path: Path,
    http: httpx.AsyncClient,
) -> None:
    swallowing = await standin(behind_standins, "swallow_start")  # type: ignore[misc]
    queueing = await standin(behind_standins, "queued_upload")  # type: ignore[misc]
    printers = [
        printer_config(behind_standins, "refuses-1").model_copy(
            update={"moonraker_url": swallowing.url}
        ),
        printer_config(behind_standins, "refuses-2").model_copy(
            update={"moonraker_url": queueing.url}
        ),
    ]
    async with live_queue(
        printers, tmp_path, http, default_database_url(tmp_path), start_within=START_WITHIN
    ) as live:
        job = await live.queue.add_job(
            "part.gcode", travel_gcode(moves=4, feedrate=6000), max_attempts=2, user="alice"
        )

        async def blocked() -> bool:
            return (await live.job(job.id)).state == "blocked"

        await wait_for(blocked, SETTLE_TIMEOUT, "the job blocked")
        attempts = await live.attempts(job.id)
        assert [(a.printer, a.state) for a in attempts] == [
            ("refuses-1", "failed_to_start"),
            ("refuses-2", "failed_to_start"),
        ]
        stored = await live.job(job.id)
        assert stored.failures == 2
        assert attempts[-1].reason
        assert attempts[-1].reason in stored.reason
        gates = await live.queue.gates()
        assert {p: g.state for p, g in gates.items()} == {
            "refuses-1": "held",
            "refuses-2": "held",
        }
        assert swallowing.starts_swallowed == [attempts[0].upload_name]
        assert queueing.starts_swallowed == [attempts[1].upload_name]
        # A blocked job stays put: nothing else was tried.
        assert len(await live.attempts(job.id)) == 2
