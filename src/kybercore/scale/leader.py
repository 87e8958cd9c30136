"""One process at a time in a role (the queue's dispatcher): a lease key in a JetStream
key-value bucket whose keys expire after the TTL.

Every TTL/3 a contender tries to create the role's key (``create`` succeeds only when it is
absent); the holder renews it with a compare-and-set on its revision. The holder gives the
role up when a renewal finds the key gone or holding another take's claim, and fences
itself when its last successful renewal was *sent* more than 0.8·TTL ago, before the key
can expire and be created by another (a full TTL after that renewal), just as slot leases
do (:mod:`.leases`). A paused holder cannot fence itself; what it does meanwhile must be
safe to do twice or refused by the database (the queue's reservations are).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
import uuid
from collections.abc import Awaitable, Callable
from typing import Final

from nats.aio.client import Client
from nats.js.errors import (
    KeyNotFoundError,
    KeyWrongLastSequenceError,
)
from nats.js.kv import KeyValue

from kybercore.aio import cancel_and_wait
from kybercore.scale.buckets import lease_bucket
from kybercore.scale.leases import FENCE_AT

log = logging.getLogger(__name__)

ROLES_BUCKET: Final = "kc_roles"

Hook = Callable[[], Awaitable[None]]


class Leadership:
    """This process's claim on one role; ``on_gain``/``on_loss`` start and stop its work."""

    def __init__(
        self, nc: Client, role: str, holder: str, *, ttl: float, on_gain: Hook, on_loss: Hook
    ) -> None:
        self._nc = nc
        self.role = role
        self.holder = holder
        self.ttl = ttl
        self._on_gain = on_gain
        self._on_loss = on_loss
        self._kv: KeyValue | None = None
        self._revision: int | None = None
        self._claim = b""  # this take's value: no other take, here or elsewhere, writes it
        self._renewed_sent = 0.0
        self._task: asyncio.Task[None] | None = None

    @property
    def held(self) -> bool:
        """Whether this process holds the role (and renewed it recently enough)."""
        return (
            self._revision is not None
            and time.monotonic() - self._renewed_sent <= FENCE_AT * self.ttl
        )

    async def start(self) -> None:
        """Open (or create) the bucket and start contending. The bucket's TTL is the one
        every contender must fence by: a process configured otherwise follows the bucket."""
        who = f"{self.holder} ({self.role} role)"
        self._kv, self.ttl = await lease_bucket(self._nc.jetstream(), ROLES_BUCKET, self.ttl, who)
        self._task = asyncio.create_task(self._loop(), name=f"role-{self.role}")

    async def stop(self) -> None:
        """Stop contending; a holder stops its work and hands the role back at once."""
        await cancel_and_wait(self._task)
        if self._revision is not None:
            with contextlib.suppress(Exception):  # the broker may be gone: the TTL frees it
                assert self._kv is not None
                await self._kv.delete(self.role, last=self._revision)
            await self._lose("stop")

    async def _loop(self) -> None:
        while True:
            started = time.monotonic()
            try:
                # A renewal stuck in a broker that does not answer must not outlast the
                # fence: the key may expire, and another take the role, right after it.
                async with asyncio.timeout(self._until_fence()):
                    await self.round()
            except Exception as exc:  # the broker away: fencing covers it; try again
                log.warning("%s: role %s round failed: %r", self.holder, self.role, exc)
            if self._revision is not None and not self.held:
                await self._lose("fence")
            wait = self.ttl / 3 - (time.monotonic() - started)
            fence = self._until_fence()
            await asyncio.sleep(max(0.0, wait if fence is None else min(wait, fence)))

    def _until_fence(self) -> float | None:
        """Seconds until a holder must fence itself without a renewal (None: not held)."""
        if self._revision is None:
            return None
        return max(0.0, self._renewed_sent + FENCE_AT * self.ttl - time.monotonic())

    async def round(self) -> None:
        """Renew the role when held, else try to take it."""
        assert self._kv is not None
        sent = time.monotonic()
        if self._revision is not None:
            try:
                self._revision = await self._kv.update(self.role, self._claim, last=self._revision)
                self._renewed_sent = sent
            except (KeyWrongLastSequenceError, KeyNotFoundError):
                if not await self._still_mine():
                    await self._lose("lost")
            return
        claim = json.dumps({"holder": self.holder, "claim": uuid.uuid4().hex}).encode()
        try:
            revision = await self._kv.create(self.role, claim)
        except KeyWrongLastSequenceError:
            return  # held by another
        self._revision, self._renewed_sent, self._claim = revision, sent, claim
        log.info("%s: took the %s role", self.holder, self.role)
        try:
            await self._on_gain()
        except BaseException:
            # Half started is not holding: stop what started, and let another take it.
            with contextlib.suppress(Exception):
                await self._kv.delete(self.role, last=revision)
            await self._lose("failed to start")
            raise

    async def _still_mine(self) -> bool:
        # A renewal stored whose reply never came back leaves the revision here one behind
        # while the key still holds this take's claim: take its revision and keep the role
        # (``_renewed_sent`` unchanged, so fencing stays on the safe side of the expiry).
        assert self._kv is not None
        try:
            entry = await self._kv.get(self.role)
        except KeyNotFoundError:
            return False
        if entry.value != self._claim:
            return False
        log.warning("%s: %s role: a renewal's reply went missing: kept", self.holder, self.role)
        self._revision = entry.revision
        return True

    async def _lose(self, why: str) -> None:
        self._revision = None
        log.info("%s: gave up the %s role (%s)", self.holder, self.role, why)
        await self._on_loss()
