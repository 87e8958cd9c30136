"""Outcomes reconciled, never missed: each queue print is followed to how it really ended,
including when it ended while KyberCore could not see the printer.

Real Moonraker + Klippy virtual printers, SQLite. KyberCore's link is dropped two ways:
Moonraker itself stopped (its history then marks the print ``interrupted``; Klippy's
``print_stats`` still names our file and says ``complete``), and KyberCore's session closed
while Moonraker records the whole print, after which Klippy restarts and forgets it (only
Moonraker's history knows how it ended).
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest

from kybercore.db import default_database_url
from kybercore.errors import ActionRejected
from kybercore.jobs.models import Attempt
from kybercore.registry.models import PrinterUpdate
from kybercore.sim.stack import PrinterStack
from tests.helpers import travel_gcode, wait_for
from tests.jobs.live_queue import LiveQueue, live_queue, printer_config

pytestmark = pytest.mark.integration

PRINT_TIMEOUT = 120.0
"""A test print lasts 10-25 s; a busy machine may take longer."""
RECONNECT_TIMEOUT = 60.0
"""Moonraker starts in ~2 s, and KyberCore reconnects within a few seconds of that."""


@pytest.fixture(scope="module")
def outcome_printer(start_stack: Callable[..., PrinterStack]) -> PrinterStack:
    """A printer for the tests that leave Moonraker running."""
    return start_stack("q-outcomes")


async def test_a_print_that_ends_while_moonraker_is_down_is_completed_when_it_is_back(
    own_printer: PrinterStack, tmp_path: Path, http: httpx.AsyncClient
) -> None:
    printers = [printer_config(own_printer, "p")]
    async with live_queue(printers, tmp_path, http, default_database_url(tmp_path)) as live:
        job = await live.queue.add_job(
            "part.gcode", travel_gcode(moves=20, feedrate=3000), user="alice"
        )
        attempt = await _wait_attempt(live, job.id, "printing")
        await wait_for(_progress_at_least(live, "p", 0.3), PRINT_TIMEOUT, "a third printed")

        own_printer.stop_moonraker()
        await wait_for(
            lambda: live.fleet.sessions.get("p").live.connection != "online",
            RECONNECT_TIMEOUT,
            "KyberCore sees the printer offline",
        )
        # The print is still running: it ends while KyberCore cannot see it.
        assert (await klippy_print_stats(own_printer))["state"] == "printing"
        await wait_for(
            _klippy_says(own_printer, "complete"), PRINT_TIMEOUT, "the print done in Klippy"
        )
        assert (await live.store.attempt(attempt.id)).state == "printing"

        own_printer.start_moonraker()
        ended = await _wait_attempt(live, job.id, "completed", RECONNECT_TIMEOUT)
        assert ended.id == attempt.id
        assert ended.print_seconds is not None
        gate = await live.gate("p")
        assert (gate.state, gate.attempt_id) == ("awaiting_clear", attempt.id)
        # Moonraker's own history lost the end (it stopped first): the outcome came from
        # Klippy's print_stats, read through Moonraker once it was back.
        history = (await http.get(f"{own_printer.url}/server/history/list")).json()["result"]
        ours = [j for j in history["jobs"] if j["filename"] == attempt.upload_name]
        assert [j["status"] for j in ours] == ["server_exit"]


async def test_a_print_that_ends_while_kybercore_is_away_is_settled_from_history(
    outcome_printer: PrinterStack, tmp_path: Path, http: httpx.AsyncClient
) -> None:
    url = outcome_printer.url
    printers = [printer_config(outcome_printer, "p")]
    async with live_queue(printers, tmp_path, http, default_database_url(tmp_path)) as live:
        job = await live.queue.add_job(
            "part.gcode", travel_gcode(moves=6, feedrate=3000), user="alice"
        )
        attempt = await _wait_attempt(live, job.id, "printing")
        await wait_for(lambda: live.queue.tracker.job_id(attempt.upload_name) is not None)

        # KyberCore lets go of the printer (its session closes) ...
        await live.fleet.update_printer("p", PrinterUpdate(enabled=False))
        # ... the print ends, and Klippy restarts: print_stats forgets the file.
        await wait_for(_moonraker_says(http, url, "complete"), PRINT_TIMEOUT, "print done")
        (await http.post(f"{url}/printer/firmware_restart")).raise_for_status()
        await wait_for(_moonraker_says(http, url, "standby"), RECONNECT_TIMEOUT, "reset")
        assert (await live.store.attempt(attempt.id)).state == "printing"

        await live.fleet.update_printer("p", PrinterUpdate(enabled=True))
        ended = await _wait_attempt(live, job.id, "completed", RECONNECT_TIMEOUT)
        history = (await http.get(f"{url}/server/history/list")).json()["result"]
        ours = [j for j in history["jobs"] if j["filename"] == attempt.upload_name]
        assert [(j["status"], j["job_id"]) for j in ours] == [("completed", ended.moonraker_job_id)]
        assert ended.print_seconds == pytest.approx(ours[0]["print_duration"])
        assert (await live.gate("p")).state == "awaiting_clear"


async def test_pause_resume_and_cancel_on_the_printer_are_what_the_attempt_says(
    outcome_printer: PrinterStack, tmp_path: Path, http: httpx.AsyncClient
) -> None:
    url = outcome_printer.url
    printers = [printer_config(outcome_printer, "p")]
    async with live_queue(printers, tmp_path, http, default_database_url(tmp_path)) as live:
        job = await live.queue.add_job(
            "part.gcode", travel_gcode(moves=30, feedrate=3000), user="alice"
        )
        await _wait_attempt(live, job.id, "printing")
        (await http.post(f"{url}/printer/print/pause")).raise_for_status()
        await _wait_attempt(live, job.id, "paused")
        (await http.post(f"{url}/printer/print/resume")).raise_for_status()
        await _wait_attempt(live, job.id, "printing")
        (await http.post(f"{url}/printer/print/cancel")).raise_for_status()
        cancelled = await _wait_attempt(live, job.id, "cancelled")
        assert cancelled.reason
        # The copy is back in the queue; the plate awaits a clear before the next one.
        assert (await live.job(job.id)).in_flight == 0
        assert (await live.gate("p")).state == "awaiting_clear"


async def test_klipper_shutting_down_mid_print_fails_the_attempt_with_its_message(
    own_printer: PrinterStack, tmp_path: Path, http: httpx.AsyncClient
) -> None:
    # Its own printer: this one stays shut down (see the note on restarts below).
    printers = [printer_config(own_printer, "p")]
    async with live_queue(printers, tmp_path, http, default_database_url(tmp_path)) as live:
        job = await live.queue.add_job(
            "part.gcode", travel_gcode(moves=30, feedrate=3000), user="alice"
        )
        await _wait_attempt(live, job.id, "printing")
        await wait_for(_homed(live, "p"), PRINT_TIMEOUT, "homed, printing the moves")
        (await http.post(f"{own_printer.url}/printer/emergency_stop")).raise_for_status()

        failed = await _wait_attempt(live, job.id, "failed")
        assert failed.reason.startswith("Klipper shut down mid-print: "), failed.reason
        stored = await live.job(job.id)
        assert (stored.in_flight, stored.failures, stored.state) == (0, 1, "queued")
        assert (await live.gate("p")).state == "awaiting_clear"
        # Not restarted here: after an emergency stop in the middle of a print, this
        # virtual printer's FIRMWARE_RESTART can wait forever behind the interrupted move
        # (a limitation of the simulator, seen without KyberCore too).


async def test_cancelling_a_job_with_a_copy_printing_asks_then_cancels_the_print(
    outcome_printer: PrinterStack, tmp_path: Path, http: httpx.AsyncClient
) -> None:
    printers = [printer_config(outcome_printer, "p")]
    async with live_queue(printers, tmp_path, http, default_database_url(tmp_path)) as live:
        job = await live.queue.add_job(
            "part.gcode", travel_gcode(moves=30, feedrate=3000), user="alice"
        )
        attempt = await _wait_attempt(live, job.id, "printing")
        with pytest.raises(ActionRejected) as refused:
            await live.queue.cancel_job(job.id, "alice", confirm=False)
        assert refused.value.code == "confirmation_required"
        assert "p" in str(refused.value)
        assert live.print_stats("p")["state"] == "printing"

        cancelled = await live.queue.cancel_job(job.id, "alice", confirm=True)
        assert cancelled.state == "cancelled"
        await wait_for(
            lambda: live.print_stats("p").get("state") == "cancelled",
            PRINT_TIMEOUT,
            "the print cancelled on the printer",
        )
        ended = await _wait_attempt(live, job.id, "cancelled")
        assert ended.id == attempt.id
        assert (await live.gate("p")).state == "awaiting_clear"


async def _wait_attempt(
    live: LiveQueue, job_id: int, state: str, timeout: float = PRINT_TIMEOUT, nth: int = 1
) -> Attempt:
    """The job's ``nth`` attempt, once it is in ``state``."""
    found: list[Attempt] = []

    async def there() -> bool:
        attempts = await live.attempts(job_id)
        found[:] = attempts[nth - 1 : nth]
        return bool(found) and found[0].state == state

    await wait_for(there, timeout, f"attempt {nth} of job {job_id} {state}")
    return found[0]


def _progress_at_least(live: LiveQueue, printer_id: str, fraction: float) -> Callable[[], bool]:
    def enough() -> bool:
        sdcard = live.fleet.sessions.get(printer_id).live.status.get("virtual_sdcard", {})
        return float(sdcard.get("progress") or 0) >= fraction

    return enough


def _homed(live: LiveQueue, printer_id: str) -> Callable[[], bool]:
    def homed() -> bool:
        toolhead = live.fleet.sessions.get(printer_id).live.status.get("toolhead", {})
        return toolhead.get("homed_axes") == "xyz"

    return homed


def _moonraker_says(http: httpx.AsyncClient, url: str, state: str) -> Callable[[], Any]:
    async def says() -> bool:
        try:
            answer = await http.get(f"{url}/printer/objects/query?print_stats")
            return bool(answer.json()["result"]["status"]["print_stats"]["state"] == state)
        except (httpx.HTTPError, KeyError, ValueError):
            return False  # Klippy restarting

    return says


def _klippy_says(stack: PrinterStack, state: str) -> Callable[[], Any]:
    async def says() -> bool:
        return bool((await klippy_print_stats(stack))["state"] == state)

    return says


async def klippy_print_stats(stack: PrinterStack) -> dict[str, Any]:
    """``print_stats`` asked of Klippy itself over its API socket (Moonraker may be down)."""
    reader, writer = await asyncio.open_unix_connection(str(stack.comms_dir / "klippy.sock"))
    try:
        request = {"id": 1, "method": "objects/query", "params": {"objects": {"print_stats": None}}}
        writer.write(json.dumps(request).encode() + b"\x03")
        await writer.drain()
        answer = json.loads((await reader.readuntil(b"\x03"))[:-1])
        return dict(answer["result"]["status"]["print_stats"])
    finally:
        writer.close()
