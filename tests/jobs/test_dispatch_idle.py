"""An empty queue costs the dispatcher nothing per printer.

Any printer's state change wakes a round, and a farm runs thousands of printers: with no
job to place, a round must not read every printer, nor a temperature update work out a
printer's heat (on a front at N = 5,000 the two were a fifth of its CPU); with one, a
storm of changes makes one round per gap, not one per change.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path
from typing import Any

from kybercore.jobs.dispatcher import Dispatcher
from kybercore.jobs.files import JobFiles
from kybercore.jobs.printers import Heat, OnChange, OnHistoryJob, QueuePrinter, Shown
from kybercore.jobs.store import JobStore
from kybercore.jobs.tracker import Tracker
from tests.jobs.conftest import new_job


class CountingPrinters:
    """A test double of the queue's printers (none configured) that counts the reads the
    dispatcher makes; nothing here is sent anywhere."""

    def __init__(self) -> None:
        self.reads = 0
        self.heats = 0
        self.listeners: list[OnChange] = []

    def all(self) -> list[QueuePrinter]:
        self.reads += 1
        return []

    def shown(self, printer_id: str) -> Shown:
        raise AssertionError("no start runs here")

    def heat(self, printer_id: str) -> Heat:
        self.heats += 1
        return Heat(heating=True, target_set=True)

    def listen(self, on_change: OnChange) -> Callable[[], None]:
        self.listeners.append(on_change)
        return lambda: self.listeners.remove(on_change)

    def listen_history(self, on_job: OnHistoryJob) -> Callable[[], None]:
        return lambda: None

    def tell(self, printer_id: str, change: Any) -> None:
        for listener in self.listeners:
            listener(printer_id, change)

    async def upload(self, printer_id: str, name: str, path: Path) -> None:
        raise AssertionError("no start runs here")

    async def start(self, printer_id: str, name: str) -> None:
        raise AssertionError("no start runs here")

    async def cancel(self, printer_id: str) -> None:
        raise AssertionError("no start runs here")

    async def history_job(
        self, printer_id: str, upload_name: str, job_id: str | None
    ) -> dict[str, Any] | None:
        return None

    async def download(self, printer_id: str, path: str) -> bytes:
        raise AssertionError("no download runs here")


async def test_an_empty_queue_reads_no_printer_until_a_job_is_queued(
    store: JobStore, tmp_path: Path
) -> None:
    printers = CountingPrinters()
    tracker = Tracker(printers, store, on_ended=lambda: None)
    dispatcher = Dispatcher(printers, store, JobFiles(tmp_path), tracker, heating_budget=3)
    unlisten = printers.listen(dispatcher._hear)
    try:
        assert (await dispatcher.round()).assignments == []
        printers.tell("p1", "heaters")
        assert (printers.reads, printers.heats) == (0, 0)

        await store.create_job(new_job(), "ana")
        await dispatcher.round()
        assert printers.reads == 1
        printers.tell("p1", "heaters")
        assert printers.heats == 1
    finally:
        unlisten()


class StormyPrinters(CountingPrinters):
    """Counting printers that change state 50 times whenever a round reads them, as a
    farm's printers do while a round plans: every change wakes the dispatcher again."""

    def __init__(self, rounds: int) -> None:
        super().__init__()
        self.changes = 0
        self.read_enough = asyncio.Event()
        self._rounds = rounds

    def all(self) -> list[QueuePrinter]:
        for printer in range(50):
            self.tell(f"p{printer}", "state")
        self.changes += 50
        if self.reads + 1 >= self._rounds:
            self.read_enough.set()
        return super().all()


async def test_a_storm_of_printer_changes_makes_one_round_per_gap(
    store: JobStore, tmp_path: Path
) -> None:
    """While a job waits, every state change wakes a round and a round reads every
    printer: a farm's changes (thousands in a bulk pause) make one round per gap."""
    printers = StormyPrinters(rounds=4)
    tracker = Tracker(printers, store, on_ended=lambda: None)
    gap = 0.2
    dispatcher = Dispatcher(printers, store, JobFiles(tmp_path), tracker, round_gap=gap)
    await store.create_job(new_job(), "ana")
    loop = asyncio.get_running_loop()
    started = loop.time()
    dispatcher.start()
    try:
        await asyncio.wait_for(printers.read_enough.wait(), 60)
        elapsed, reads = loop.time() - started, printers.reads
    finally:
        await dispatcher.stop()
    # Rounds start at least a gap apart, however slow the machine: never more than this.
    assert reads <= elapsed / gap + 1, (reads, elapsed)
    assert printers.changes >= 50 * reads
