"""Lease renewals on a thread of their own, with a NATS connection of their own.

A worker's event loop runs seconds late when ingest takes its core (at 5,000 printers on two
shared cores, 2 s and more). Renewed on that loop, the leases missed the fence (0.8·TTL):
every one was dropped and claimed again, and each flap closed and reopened printers'
sessions, which made the loop later still. Here a renewal goes out on time however late the
worker's loop runs.

Only while that loop is alive, though: one that has not turned for :data:`LOOP_GRACE` TTLs
(hung, not just late) must not hold its printers for ever, so the renewals stop and its
leases expire as a dead worker's do. A paused process (SIGSTOP) pauses this thread too.

The thread only renews. What a renewal learns (the slot is someone else's now) goes back to
the worker's loop, which drops the slot; claims, releases, fencing and the own/drop log all
stay on that loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections.abc import Awaitable, Callable
from typing import Final

from nats.aio.client import Client
from nats.js.kv import KeyValue

from kybercore.scale.broker import connect, jetstream

log = logging.getLogger(__name__)

LOOP_GRACE: Final = 5.0
"""TTLs the worker's loop may go without turning before its leases are left to expire."""
RETRY_SECONDS: Final = 0.5
"""Between attempts to connect the renewals' own connection."""

Renew = Callable[[KeyValue], Awaitable[None]]
"""Renews every slot held, through the given bucket (this thread's)."""


class Renewer:
    """Calls ``renew`` every ``every`` seconds on a thread of its own, while ``alive()``."""

    def __init__(
        self, url: str, name: str, bucket: str, every: float,
        renew: Renew, alive: Callable[[], bool], *, local: bool = False,
    ) -> None:  # fmt: skip
        """``local``: the bucket is in the connected server's own JetStream (:func:`jetstream`)."""
        self._url = url
        self._local = local
        self._name = name
        self._bucket = bucket
        self._every = every
        self._renew = renew
        self._alive = alive
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._task: asyncio.Task[None] | None = None
        self._ready = threading.Event()

    async def start(self) -> None:
        """Start the thread; return once it can be stopped."""
        self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
        self._thread.start()
        await asyncio.to_thread(self._ready.wait)

    async def stop(self) -> None:
        """Stop renewing, a renewal on its way included (the broker may be away), and wait
        for the thread, its connection closed."""
        thread, self._thread = self._thread, None
        if thread is None:
            return
        await asyncio.to_thread(self._ready.wait)  # stopped as it started: wait for its loop
        assert self._loop is not None
        assert self._task is not None
        with contextlib.suppress(RuntimeError):  # its loop has ended already
            self._loop.call_soon_threadsafe(self._task.cancel)
        await asyncio.to_thread(thread.join)

    def _run(self) -> None:
        with contextlib.suppress(asyncio.CancelledError):
            asyncio.run(self._main())

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._task = asyncio.current_task()
        self._ready.set()
        nc: Client | None = None
        kv: KeyValue | None = None
        try:
            while True:
                started = time.monotonic()
                try:
                    if nc is None:
                        nc = await connect(self._url, self._name)
                    if kv is None:
                        kv = await jetstream(nc, local=self._local).key_value(self._bucket)
                    if self._alive():
                        await self._renew(kv)
                    else:
                        log.warning("%s: the worker's loop is hung: leases left", self._name)
                    wait = self._every - (time.monotonic() - started)
                except Exception as exc:  # the broker away: the worker's loop fences
                    log.warning("%s: lease renewal failed: %s", self._name, exc)
                    wait = RETRY_SECONDS if nc is None else self._every
                await asyncio.sleep(max(0.0, wait))
        finally:
            if nc is not None:
                await nc.close()
