"""Staggered starts: twelve printers on one circuit, at most three heating at once.

Twelve real virtual printers (Moonraker + Klippy + virtual MCU each) in one power group, a
job of twelve copies whose file heats bed and hotend for real (M140/M104, then M190/M109).
Every status update of every printer is a sample: at none of them are more than K = 3
printers heating (a target set, more than a few degrees below it), and the budget is really
used (some sample sees three).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from kybercore.db import default_database_url
from kybercore.jobs.rules import is_heating
from kybercore.moonraker.events import SessionEvent, StatusDelta, StatusSnapshot
from kybercore.sim.stack import PrinterStack
from tests.helpers import wait_for
from tests.jobs.live_queue import heating_gcode, live_queue, printer_config

pytestmark = pytest.mark.integration

PRINTERS = 12
BUDGET = 3
HEAT_RATE = 2.0
"""Slower than the other tests' heaters (8): heating lasts ~15 s, so starts overlap."""
ALL_DONE_TIMEOUT = 600.0
"""Four waves of three (~40 s each on a busy 2-core machine), with slack."""


@pytest.fixture(scope="module")
def twelve_printers(start_stack: Callable[..., PrinterStack]) -> list[PrinterStack]:
    """Twelve virtual printers with slow heaters."""
    return [start_stack(f"q-heat-{i:02}", heat_rate=HEAT_RATE) for i in range(PRINTERS)]


@pytest.mark.timeout(900)
async def test_at_most_three_of_twelve_printers_heat_at_once(
    twelve_printers: list[PrinterStack], tmp_path: Path, http: httpx.AsyncClient
) -> None:
    printers = [
        printer_config(stack, f"heat-{i:02}", location="Room A")
        for i, stack in enumerate(twelve_printers)
    ]
    async with live_queue(
        printers, tmp_path, http, default_database_url(tmp_path), heating_budget=BUDGET
    ) as live:
        samples: list[int] = []

        def sample(_printer_id: str, event: SessionEvent) -> None:
            if isinstance(event, StatusDelta | StatusSnapshot):
                samples.append(sum(is_heating(p.live.status) for p in live.fleet.sessions.all()))

        stop_sampling = live.fleet.listen(sample)
        try:
            job = await live.queue.add_job(
                "hot.gcode", heating_gcode(), quantity=PRINTERS, user="alice"
            )

            async def waiting_for_power() -> bool:
                lines = await live.queue.why(job.id)
                return any(line.code == "waiting_for_power" for line in lines)

            # While the budget is full, the job says so.
            await wait_for(waiting_for_power, ALL_DONE_TIMEOUT, "'waiting for power' in why")

            async def every_copy_printed() -> bool:
                attempts = await live.attempts(job.id)
                return len(attempts) == PRINTERS and all(a.state == "completed" for a in attempts)

            await wait_for(every_copy_printed, ALL_DONE_TIMEOUT, "all twelve copies printed")
        finally:
            stop_sampling()

        attempts = await live.attempts(job.id)
        assert sorted(a.printer for a in attempts) == sorted(p.id for p in printers)
        assert samples, "no status update was sampled"
        assert max(samples) <= BUDGET, f"{max(samples)} heating at once"
        assert max(samples) == BUDGET, "the budget was never used in full"
