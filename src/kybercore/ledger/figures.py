"""The figures ``/metrics`` shows that are read in the background, so that a scrape reads
only memory: the queue's gates and depth and the job counts (from the database, every few
seconds) and the event loop's lag. :class:`~kybercore.ledger.service.LedgerService` keeps
them on ``serve`` (and on an ingest worker), :mod:`kybercore.scale.front_metrics` on a front.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from typing import Final

from sqlalchemy import func, select
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.db import reading
from kybercore.db.outage import UNAVAILABLE, Outage
from kybercore.jobs.tables import gates, jobs
from kybercore.ledger.metrics import QueueFigures

log = logging.getLogger(__name__)

LAG_EVERY: Final = 0.5


async def poll(read: Callable[[], Awaitable[None]], every: float, what: str) -> None:
    """Run ``read`` now and every ``every`` seconds, until cancelled. A database away is
    logged once per outage (the figures last read stand meanwhile); ``what`` names them."""
    outage = Outage(log, f"read {what}", "the figures last read stand meanwhile")
    while True:
        try:
            await read()
        except UNAVAILABLE as exc:
            outage.failed(exc)
        else:
            outage.ended()
        await asyncio.sleep(every)


class QueueReader:
    """The queue's gates and depth, as last read (one query each)."""

    def __init__(self, engine: AsyncEngine) -> None:
        self._engine = engine
        self.gates: dict[str, str] = {}
        """Each printer's gate state (the timeline's ``awaiting_clear`` and ``maintenance``)."""
        self.figures = QueueFigures()

    async def read(self) -> None:
        """Read the gates and the depth again."""
        queued = jobs.c.state == "queued"
        async with reading(self._engine) as conn:
            found = await conn.execute(select(gates.c.printer, gates.c.state))
            read_gates = {printer: state for printer, state in found}
            count, left, oldest = (
                await conn.execute(
                    select(
                        func.count(),
                        func.sum(jobs.c.quantity - jobs.c.done - jobs.c.in_flight),
                        func.min(jobs.c.created_at),
                    ).where(queued)
                )
            ).one()
        self.gates = read_gates
        self.figures = QueueFigures.of(int(count or 0), int(left or 0), oldest)


class LoopLag:
    """How late the event loop last ran a timer of :data:`LAG_EVERY` seconds."""

    def __init__(self) -> None:
        self.seconds = 0.0

    async def run(self) -> None:
        """Measure until cancelled."""
        loop = asyncio.get_running_loop()
        while True:
            before = loop.time()
            await asyncio.sleep(LAG_EVERY)
            self.seconds = max(0.0, loop.time() - before - LAG_EVERY)
