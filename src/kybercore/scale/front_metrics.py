"""``/metrics`` on a front on NATS: the same names and format as on ``serve``
(:mod:`kybercore.ledger.metrics`), from what the front holds.

- The printers, their heaters and progress: the views the front follows (:mod:`.front`).
  A printer whose slot's owner went silent is counted under the connection ``stale``, and
  its state is ``stale``; its last readings are left out.
- Each printer's state: the one its owner's ledger writes to the timeline
  (:func:`~kybercore.ledger.timeline.printer_state`), named from its view and its gate.
- The queue's depth and gates, and the jobs by outcome: read from the shared database in
  the background by the ledger's own readers (:mod:`kybercore.ledger.figures`), never at a
  scrape. The job counts group the whole history table, so they are read less often.
- The browsers and the event loop's lag: this front's; and each worker's slots and loop
  lag, as its latest patch batch or heartbeat says (a worker whose loop runs a second late
  is near the point where its printers turn stale).

Moonraker's reconnects are counted where the sessions are, in the ingest workers: a front
leaves them out rather than fetch them from every worker at every scrape.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterable, Mapping
from typing import Any, Final

from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.aio import cancel_and_wait
from kybercore.ledger.figures import LoopLag, QueueReader, poll
from kybercore.ledger.history import HistoryStore
from kybercore.ledger.metrics import STALE, Snapshot
from kybercore.ledger.timeline import printer_state
from kybercore.scale.front import FrontFleet

QUEUE_POLL: Final = 2.0
"""Seconds between reads of the queue's gates and depth (as the ledger's)."""
JOBS_POLL: Final = 10.0
"""Seconds between reads of the job counts."""


def printer_states(views: Iterable[Mapping[str, Any]], gates: Mapping[str, str]) -> dict[str, str]:
    """Each printer's timeline state, from its view and its queue gate; ``stale`` for a
    view no worker reports now (what its owner wrote last may no longer hold)."""
    states: dict[str, str] = {}
    for view in views:
        printer, connection = str(view["id"]), str(view["connection"])
        if connection == STALE:
            states[printer] = STALE
            continue
        klippy = str(view["klippy_state"])
        print_state = str((view.get("job") or {}).get("state") or "")
        states[printer] = printer_state(connection, klippy, print_state, gates.get(printer))
    return states


class FrontMetrics:
    """The figures of a front's ``/metrics`` (a :class:`~kybercore.ledger.metrics.Source`)."""

    def __init__(
        self,
        fleet: FrontFleet,
        engine: AsyncEngine,
        *,
        queue_poll: float = QUEUE_POLL,
        jobs_poll: float = JOBS_POLL,
    ) -> None:
        """``engine``: the database the workers' ledgers and the queue share."""
        self._fleet = fleet
        self._history = HistoryStore(engine)
        self._queue = QueueReader(engine)
        self._lag = LoopLag()
        self._polls = (queue_poll, jobs_poll)
        self._job_counts: dict[tuple[str, str], int] = {}
        self._tasks: list[asyncio.Task[None]] = []

    async def start(self) -> None:
        """Start reading the database and measuring the loop, in the background."""
        queue_poll, jobs_poll = self._polls
        self._tasks = [
            asyncio.create_task(
                poll(self._queue.read, queue_poll, "the queue's gates and depth"),
                name="metrics-queue",
            ),
            asyncio.create_task(
                poll(self._read_job_counts, jobs_poll, "the job counts"), name="metrics-jobs"
            ),
            asyncio.create_task(self._lag.run(), name="metrics-loop-lag"),
        ]

    async def stop(self) -> None:
        """Stop reading and measuring."""
        for task in self._tasks:
            await cancel_and_wait(task)
        self._tasks.clear()

    async def _read_job_counts(self) -> None:
        self._job_counts = await self._history.counts()

    def metrics(self) -> Snapshot:
        """What ``/metrics`` shows now (a copy: format it anywhere)."""
        views = self._fleet.views()
        return Snapshot(
            views=views,
            states=printer_states(views, self._queue.gates),
            jobs=self._job_counts,  # replaced, never changed in place
            queue=self._queue.figures,
            reconnects={},
            browsers=self._fleet.hub.client_count,
            loop_lag=self._lag.seconds,
            workers={w: (s.slots, s.loop_lag) for w, s in self._fleet.copy.workers().items()},
            broker_connected=self._fleet.broker_connected,
        )
