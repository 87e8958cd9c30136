"""The outbox worker: sends every pending delivery, retries with backoff, survives restarts.

Its queue is the database (:class:`~kybercore.notify.store.NotifyStore`): on start it sends
whatever a previous run left pending, and a delivery is pending until the receiver took it.
Each due delivery is sent by a task of its own, so one slow receiver holds back only its
own (channel, printer) line, never the others. A failed attempt (any non-2xx answer or
transport error) is tried again after ``first_retry * 2**(attempts-1)`` seconds, capped at
``max_retry``, with jitter; once ``give_up_after`` seconds have passed since the delivery was
recorded, it is ``failed`` and its printer's later deliveries go on.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import time
from datetime import UTC, datetime, timedelta
from typing import Final

import httpx

from kybercore.aio import cancel_and_wait
from kybercore.notify.records import Delivery, DueDelivery
from kybercore.notify.senders import SendResult, send_apprise, send_webhook
from kybercore.notify.store import NotifyStore
from kybercore.notify.texts import render

log = logging.getLogger(__name__)

MAX_SENDING: Final = 20
"""Deliveries sent at once (each to a different channel or printer)."""
STORE_CALLS_AT_ONCE: Final = 2
"""Database calls the sends make at once (a snapshot read, an outcome written): the sends
wait on their receivers, not on the database, and the fleet's own writes share its pool."""
STOP_GRACE: Final = 5.0
"""Seconds :meth:`Outbox.stop` lets sends in flight finish, by default, before cutting
them off."""
OUTCOME_POLL: Final = 0.5
"""Seconds between reads of a delivery awaited by :meth:`Outbox.wait_outcome`."""
_IDLE_CHECK: Final = 60.0
# Without anything pending the loop still looks every minute: another process on the same
# database may have recorded events (this one's record() wakes it at once).


class Outbox:
    """Sends the store's pending deliveries until stopped."""

    def __init__(
        self,
        store: NotifyStore,
        http: httpx.AsyncClient,
        *,
        first_retry: float = 2.0,
        max_retry: float = 300.0,
        give_up_after: float = 48 * 3600.0,
        stop_grace: float = STOP_GRACE,
    ) -> None:
        self._store = store
        self._http = http
        self.first_retry = first_retry
        self.max_retry = max_retry
        self.give_up_after = give_up_after
        self.stop_grace = stop_grace
        self._wake = asyncio.Event()
        self._runner: asyncio.Task[None] | None = None
        self._stopping = False
        self._sending: dict[int, asyncio.Task[None]] = {}
        self._outcomes: dict[int, asyncio.Event] = {}
        self._store_calls = asyncio.Semaphore(STORE_CALLS_AT_ONCE)

    async def start(self) -> None:
        """Start sending, beginning with whatever a previous run left pending."""
        if self._runner is None:
            self._stopping = False
            self._runner = asyncio.create_task(self._run(), name="notify-outbox")

    async def stop(self) -> None:
        """Stop: sends in flight get ``stop_grace`` seconds to finish; those cut off are
        handed back to the database, due now, for the next start."""
        runner, self._runner = self._runner, None
        if runner is not None:
            # Asked, not cancelled: a claim cut off between its commit and its tasks would
            # leave deliveries claimed by no one until their lease ends.
            self._stopping = True
            self._wake.set()
            await asyncio.wait({runner}, timeout=self.stop_grace)
            await cancel_and_wait(runner)
        if self._sending:
            await asyncio.wait(list(self._sending.values()), timeout=self.stop_grace)
        cut = list(self._sending)
        for task in list(self._sending.values()):
            await cancel_and_wait(task)
        self._sending.clear()
        await self._store.release(cut)

    def wake(self) -> None:
        """Look for due deliveries now (call after :meth:`NotifyStore.record`)."""
        self._wake.set()

    async def wait_outcome(self, delivery_id: int, timeout: float) -> Delivery:
        """The delivery once its first attempt is over (delivered, or failed and waiting for
        a retry), or as it stands after ``timeout`` seconds. This outbox's own sends are
        heard at once; another process's (the front running the notifier, on NATS) are read
        from the database every :data:`OUTCOME_POLL` seconds."""
        settled = self._outcomes.setdefault(delivery_id, asyncio.Event())
        deadline = time.monotonic() + timeout
        try:
            while True:
                current = await self._store.delivery(delivery_id)
                left = deadline - time.monotonic()
                if current.attempts > 0 or current.status != "pending" or left <= 0:
                    return current
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(settled.wait(), min(left, OUTCOME_POLL))
        finally:
            self._outcomes.pop(delivery_id, None)

    # -- the loop ----------------------------------------------------------------------

    async def _run(self) -> None:
        while not self._stopping:
            # Cleared before looking: a wake() from now on interrupts the wait below.
            self._wake.clear()
            try:
                await self._claim()
                pause = await self._until_next()
            except Exception:
                # The database may be restarting; the deliveries wait there meanwhile.
                log.exception("Notification outbox: cannot read the pending deliveries")
                pause = self.first_retry
            if self._stopping:
                return
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), pause)

    async def _claim(self) -> None:
        free = MAX_SENDING - len(self._sending)
        if free <= 0:
            return
        for due in await self._store.due(_now(), limit=free):
            task = asyncio.create_task(self._send(due), name=f"notify-delivery-{due.id}")
            self._sending[due.id] = task

    async def _until_next(self) -> float:
        if len(self._sending) >= MAX_SENDING:
            return _IDLE_CHECK  # a finished send wakes the loop
        when = await self._store.next_due()
        if when is None:
            return _IDLE_CHECK
        return max(0.0, min((when - _now()).total_seconds(), _IDLE_CHECK))

    async def _send(self, due: DueDelivery) -> None:
        try:
            result = await self._attempt(due)
            async with self._store_calls:
                await self._record(due, result)
        except Exception:
            log.exception("Notification delivery %d: could not send or record it", due.id)
        finally:
            self._sending.pop(due.id, None)
            if (waiter := self._outcomes.get(due.id)) is not None:
                waiter.set()
            self._wake.set()

    async def _attempt(self, due: DueDelivery) -> SendResult:
        title, body = render(due.event, due.rules.language)
        snapshot = None
        if due.has_snapshot and due.rules.attach_snapshot:
            async with self._store_calls:
                snapshot = await self._store.snapshot(due.event.id)
        if due.channel_kind == "webhook":
            return await send_webhook(
                self._http, due.target, due.secret, due.event, title, body, snapshot
            )
        return await send_apprise(due.target, title, body, snapshot, severity=due.event.severity)

    async def _record(self, due: DueDelivery, result: SendResult) -> None:
        if result.ok:
            await self._store.mark_delivered(due.id, result.code)
            return
        now = _now()
        attempts = due.attempts + 1
        deadline = due.created_at + timedelta(seconds=self.give_up_after)
        if now >= deadline:
            log.warning(
                "Notification delivery %d given up after %d attempts: %s",
                due.id, attempts, result.error,
            )  # fmt: skip
            await self._store.mark_failed(due.id, result.error, result.code)
            return
        # The last try falls on the deadline, not after it.
        delay = backoff(attempts, self.first_retry, self.max_retry)
        retry_at = min(now + timedelta(seconds=delay), deadline)
        log.info(
            "Notification delivery %d failed (attempt %d: %s); next try at %s",
            due.id, attempts, result.error, retry_at.isoformat(timespec="seconds"),
        )  # fmt: skip
        await self._store.mark_retry(due.id, result.error, result.code, retry_at)


def backoff(attempts: int, first: float, cap: float) -> float:
    """Seconds before the next try after ``attempts`` failed ones: ``first * 2**(attempts-1)``
    capped at ``cap``, jittered into its upper half (receivers that were down together are
    not all hit again at the same instant)."""
    ceiling = min(cap, first * 2 ** max(attempts - 1, 0))
    return float(ceiling / 2 + random.uniform(0, ceiling / 2))


def _now() -> datetime:
    return datetime.now(UTC)
