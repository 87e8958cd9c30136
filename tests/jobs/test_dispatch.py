"""The dispatch loop on real printers: a job of five PLA copies on a fleet of two PLA
printers and one PETG printer, cleared by an operator copy after copy (one plate bad).

Real Moonraker + Klippy virtual printers, and the real database: the module runs on
SQLite and on PostgreSQL (the ``database_url`` fixture).
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

import httpx
import pytest

from kybercore.jobs.models import Requirements
from kybercore.sim.stack import PrinterStack
from tests.helpers import travel_gcode, wait_for
from tests.jobs.live_queue import LiveQueue, live_queue, printer_config

pytestmark = pytest.mark.integration

COPIES = 5
PRINT_TIMEOUT = 120.0
"""A copy (G28 and a few travel moves) prints in ~10 s; a busy machine may take longer."""


@pytest.fixture(scope="module")
def three_printers(start_stack: Callable[..., PrinterStack]) -> list[PrinterStack]:
    """Two printers that will hold PLA and one that will hold PETG (set in printers.json)."""
    return [start_stack("q-pla-1"), start_stack("q-pla-2"), start_stack("q-petg")]


async def test_five_pla_copies_run_only_on_pla_printers_each_after_a_clear(
    three_printers: list[PrinterStack],
    tmp_path: Path,
    http: httpx.AsyncClient,
    database_url: str,
) -> None:
    pla_1, pla_2, petg = three_printers
    printers = [
        printer_config(pla_1, "pla-1", capabilities={"material": "PLA"}),
        printer_config(pla_2, "pla-2", capabilities={"material": "PLA"}),
        printer_config(petg, "petg", capabilities={"material": "PETG"}),
    ]
    async with live_queue(printers, tmp_path, http, database_url) as live:
        job = await live.queue.add_job(
            "bracket.gcode",
            travel_gcode(moves=4, feedrate=6000),
            quantity=COPIES,
            requirements=Requirements(material="PLA"),
            user="alice",
        )
        # Why it does not run on the PETG printer, asked while it runs elsewhere.
        await wait_for(lambda: _any_printing(live), PRINT_TIMEOUT, "a first copy printing")
        petg_lines = [line for line in await live.queue.why(job.id) if line.subject == "petg"]
        assert petg_lines, await live.queue.why(job.id)
        assert any("PETG" in line.en and "PLA" in line.en for line in petg_lines), petg_lines
        assert all(line.es for line in petg_lines)

        verdicts = ["good", "bad", "good", "good", "good", "good"]
        cleared_at: dict[str, list[datetime]] = {"pla-1": [], "pla-2": []}
        while verdicts:
            printer_id = await _next_awaiting_clear(live)
            gate = await live.gate(printer_id)
            ended = await live.store.attempt(gate.attempt_id or -1)
            assert ended.state == "completed", ended
            assert ended.printer == printer_id
            # No second attempt on a printer whose plate was not cleared.
            on_printer = [a for a in await live.attempts(job.id) if a.printer == printer_id]
            assert len(on_printer) == len(cleared_at[printer_id]) + 1, on_printer
            cleared_at[printer_id].append(datetime.now(UTC))
            await live.queue.clear(printer_id, verdicts.pop(0), cause="stringing", user="bob")

        await wait_for(
            _job_done(live, job.id), PRINT_TIMEOUT, f"job {job.id} done after the last clear"
        )
        done = await live.job(job.id)
        assert (done.state, done.done, done.in_flight) == ("done", COPIES, 0)

        attempts = await live.attempts(job.id)
        assert {a.printer for a in attempts} <= {"pla-1", "pla-2"}
        assert all(a.state == "completed" for a in attempts), attempts
        assert sorted(a.verdict or "" for a in attempts) == ["bad"] + ["good"] * COPIES
        assert [a.cause for a in attempts if a.verdict == "bad"] == ["stringing"]
        good_copies = sorted(a.copy for a in attempts if a.verdict == "good")
        assert good_copies == list(range(1, COPIES + 1))
        # Every later attempt on a printer was created after the clear before it.
        for printer_id, clears in cleared_at.items():
            later = [a for a in attempts if a.printer == printer_id][1:]
            for attempt, cleared in zip(later, clears, strict=False):
                assert attempt.created_at > cleared, (attempt, cleared)
        assert all(a.moonraker_job_id for a in attempts), attempts
        assert len({a.upload_name for a in attempts}) == len(attempts)

        gates = await live.queue.gates()
        assert gates.get("petg") is None or gates["petg"].attempt_id is None
        assert all(g.state == "available" for g in gates.values()), gates


def _any_printing(live: LiveQueue) -> bool:
    return any(
        live.print_stats(pid).get("state") == "printing"
        and str(live.print_stats(pid).get("filename", "")).startswith("kybercore/")
        for pid in ("pla-1", "pla-2")
    )


async def _next_awaiting_clear(live: LiveQueue) -> str:
    """The first printer whose plate awaits a clear (waits for one)."""
    found: list[str] = []

    async def awaiting() -> bool:
        gates = await live.queue.gates()
        found[:] = sorted(p for p, g in gates.items() if g.state == "awaiting_clear")
        return bool(found)

    await wait_for(awaiting, PRINT_TIMEOUT, "a printer awaiting a clear")
    return found[0]


def _job_done(live: LiveQueue, job_id: int) -> Callable[[], object]:
    async def done() -> bool:
        return (await live.job(job_id)).state == "done"

    return done
