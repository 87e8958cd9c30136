"""Which worker owns which slot: leases in a JetStream key-value bucket.

Every TTL/3 a worker renews each slot it owns, all at once, with a compare-and-set on the
key's revision (a failure means someone else holds it now: the slot is dropped at once).
The renewals run on their own, apart from the rounds that share the slots out: on a loop
starved by ingest, counting the workers (several round trips) or claiming delayed the
renewals past the fence, and every lease was dropped and claimed again.

Every TTL/3, too, a round:

1. writes its heartbeat into ``kc_workers`` (a bucket whose keys expire after the TTL), and
   counts the live workers: its fair share is ``ceil(S / workers)``;
2. releases the slots above its share (a delete, also compare-and-set);
3. creates free slots (``create`` succeeds only if the key is absent) up to its share: it
   reads the other slots' keys at once, and creates as many free ones at once as it lacks.

A slot whose last successful renewal was *sent* more than 0.8·TTL ago is fenced: the worker
stops acting for it before the key can expire and be created by another worker (a full TTL
after that renewal). A paused process cannot fence itself; the revision at create is the
slot's epoch, carried on everything the owner publishes, so its late messages are ignored.

Every gain and loss is written as a JSON line (``own``/``drop``) so that ownership can be
replayed: per slot, intervals of different workers must never overlap.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections.abc import Awaitable, Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Final, TypeVar, cast

from nats.aio.client import Client
from nats.js.errors import KeyNotFoundError, KeyWrongLastSequenceError, NoKeysError
from nats.js.kv import KeyValue

from kybercore.aio import cancel_and_wait
from kybercore.scale.slots import fair_share, slot_key

log = logging.getLogger(__name__)

SLOTS_BUCKET: Final = "kc_slots"
WORKERS_BUCKET: Final = "kc_workers"
FENCE_AT: Final = 0.8
"""Of the TTL: a slot not renewed for this long is no longer acted on."""
T = TypeVar("T")


@dataclass
class Held:
    """A slot this worker owns."""

    epoch: int
    """The key's revision when this worker created it."""
    revision: int
    """The key's revision after the last renewal (the next compare-and-set's)."""
    renewed_sent: float
    """monotonic() when the last successful renewal was sent."""


Change = Callable[[int, int | None, str], None]
"""Told ``(slot, epoch, "")`` when a slot is gained, ``(slot, None, why)`` when it is lost:
``why`` is ``lost`` (another worker has it), ``fence``, ``release`` (handed to a peer for
a fair share) or ``stop``."""


class Leases:
    """One worker's side of slot ownership; see the module docstring."""

    def __init__(
        self, nc: Client, worker: str, *, slots: int, ttl: float,
        log_path: Path | None = None, on_change: Change | None = None,
    ) -> None:  # fmt: skip
        self._nc = nc
        self.worker = worker
        self.slots = slots
        self.ttl = ttl
        self._log_path = log_path
        self._on_change = on_change
        self._held: dict[int, Held] = {}
        self._kv: KeyValue | None = None
        self._workers: KeyValue | None = None
        self._task: asyncio.Task[None] | None = None
        self._pending: list[str] = []
        self._flushing = asyncio.Lock()

    async def start(self) -> None:
        """Open (or create) the buckets and start the renewal loop."""
        js = self._nc.jetstream()
        self._kv = await js.create_key_value(bucket=SLOTS_BUCKET, ttl=self.ttl, history=1)
        self._workers = await js.create_key_value(bucket=WORKERS_BUCKET, ttl=self.ttl, history=1)
        self._task = asyncio.create_task(self._loop(), name=f"leases-{self.worker}")

    async def stop(self, release: bool = True) -> None:
        """Stop renewing; with ``release``, hand every slot back at once (a clean exit)."""
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        for slot in list(self._held):
            held = self._held.get(slot)
            if held is None:  # fenced while an earlier delete was awaited
                continue
            self._drop(slot, "stop")  # before the delete, as a release is
            if release:
                with contextlib.suppress(Exception):  # the broker may be gone: TTL frees it
                    assert self._kv is not None
                    await self._kv.delete(slot_key(slot), last=held.revision)
        await self.flush_log()

    def epoch(self, slot: int) -> int | None:
        """The slot's epoch if this worker may act for it now, else None (fencing it if its
        last renewal is too old)."""
        held = self._held.get(slot)
        if held is None:
            return None
        if time.monotonic() - held.renewed_sent > FENCE_AT * self.ttl:
            self._drop(slot, "fence", at=held.renewed_sent + FENCE_AT * self.ttl)
            return None
        return held.epoch

    def owned(self) -> dict[int, int]:
        """``slot → epoch`` of every slot this worker may act for now."""
        return {s: e for s in list(self._held) if (e := self.epoch(s)) is not None}

    async def _loop(self) -> None:
        # Announce this worker and wait one round before claiming: workers started together
        # then see each other and take their shares at once, rather than the first taking
        # every slot (and every printer's connection) only to hand half of them back.
        with contextlib.suppress(Exception):  # the broker away: the rounds say so
            assert self._workers is not None
            await self._workers.put(self.worker, b"1")
            await asyncio.sleep(self.ttl / 3)
        # A child of this task: cancelling it (a stop, or a test standing in for a paused
        # process) stops the renewals too. The methods are looked up at each call (a test
        # counts the rounds by wrapping them).
        renewing = asyncio.create_task(self._every_third(lambda: self.renew(), "renewal"))
        try:
            await self._every_third(lambda: self.round(), "round")
        finally:
            await cancel_and_wait(renewing)

    async def _every_third(self, work: Callable[[], Awaitable[None]], what: str) -> None:
        while True:
            started = time.monotonic()
            try:
                await work()
            except Exception as exc:  # the broker away: fencing covers it; try again
                log.warning("%s: lease %s failed: %s", self.worker, what, exc)
            self.owned()  # fence what is too old now
            await self.flush_log()
            await asyncio.sleep(max(0.0, self.ttl / 3 - (time.monotonic() - started)))

    async def renew(self) -> None:
        """Renew every slot held, all at once: a KV call waits for several turns of the
        event loop, and on a loop starved by ingest 32 renewals in turn outlasted the fence
        (3.4 s at 15 ms a turn)."""
        await _all(self._renew(slot, held) for slot, held in list(self._held.items()))

    async def round(self) -> None:
        """One heartbeat, release and claim pass."""
        assert self._kv is not None
        assert self._workers is not None
        await self._workers.put(self.worker, b"1")
        try:
            workers = len(await self._workers.keys())
        except NoKeysError:
            workers = 1
        share = fair_share(self.slots, workers)
        self.owned()
        for slot in sorted(self._held)[share:]:
            # Let go before the delete is sent: a peer may create the key as soon as the
            # delete lands, long before its reply is read on a starved loop.
            held = self._held.get(slot)
            if held is None:  # fenced (the worker asked for its epoch) during a delete
                continue
            self._drop(slot, "release")
            with contextlib.suppress(KeyWrongLastSequenceError, KeyNotFoundError):
                await self._kv.delete(slot_key(slot), last=held.revision)
        await self._claim(share)

    async def _renew(self, slot: int, held: Held) -> None:
        assert self._kv is not None
        sent = time.monotonic()
        try:
            value = self._value(held.epoch)
            held.revision = await self._kv.update(slot_key(slot), value, last=held.revision)
            held.renewed_sent = sent
        except (KeyWrongLastSequenceError, KeyNotFoundError):
            if self._held.get(slot) is held:  # not released (or claimed again) meanwhile
                self._drop(slot, "lost")

    async def _claim(self, share: int) -> None:
        # Every other slot's key is read at once, then free slots are created, as many at
        # once as the share lacks (more would go back next round, printers and all). Slot by
        # slot, a create cost two KV calls per slot a peer holds, and a worker below its share
        # delayed the next round's renewals past the fence.
        if len(self._held) >= share:
            return
        others = [slot for slot in range(self.slots) if slot not in self._held]
        taken = await _all(self._taken(slot) for slot in others)
        free = [slot for slot, busy in zip(others, taken, strict=True) if not busy]
        while free and (need := share - len(self._held)) > 0:
            batch, free = free[:need], free[need:]
            await _all(self._create(slot) for slot in batch)

    async def _taken(self, slot: int) -> bool:
        assert self._kv is not None
        try:
            await self._kv.get(slot_key(slot))
        except KeyNotFoundError:  # never written, expired, or deleted
            return False
        return True

    async def _create(self, slot: int) -> None:
        assert self._kv is not None
        sent = time.monotonic()
        try:
            revision = await self._kv.create(slot_key(slot), self._value(0))
        except KeyWrongLastSequenceError:
            return  # taken since it was read
        except KeyNotFoundError:
            # nats-py's create reads the key back after a failed compare-and-set; a lease
            # expiring in between fails that read. The slot is free next round.
            return
        self._held[slot] = Held(revision, revision, sent)
        self._write("own", slot, revision)
        if self._on_change:
            self._on_change(slot, revision, "")

    def _value(self, epoch: int) -> bytes:
        return json.dumps({"w": self.worker, "epoch": epoch}).encode()

    def _drop(self, slot: int, why: str, at: float | None = None) -> None:
        held = self._held.pop(slot, None)
        if held is None:
            return
        log.info("%s: slot %d dropped (%s)", self.worker, slot, why)
        self._write("drop", slot, held.epoch, why=why, at=at)
        if self._on_change:
            self._on_change(slot, None, why)

    def _write(
        self, event: str, slot: int, epoch: int, why: str = "", at: float | None = None
    ) -> None:
        # "at": when it took effect; a fence takes effect 0.8·TTL after the last renewal,
        # however late it is noticed. Wall time lets logs of several processes be merged.
        wall = time.time() - (time.monotonic() - at) if at is not None else time.time()
        line = {"ev": event, "slot": slot, "epoch": epoch, "worker": self.worker, "why": why}
        self._pending.append(json.dumps({**line, "t": wall}))

    async def flush_log(self) -> None:
        """Append the changes noted since the last flush to the log (off the event loop)."""
        async with self._flushing:  # the renewals' and the rounds': lines stay in order
            lines, self._pending = self._pending, []
            if lines and self._log_path is not None:
                await asyncio.to_thread(_append, self._log_path, lines)


async def _all(calls: Iterable[Awaitable[T]]) -> list[T]:
    # Every call runs to its end before the first error is raised: a broker error on one
    # slot must not leave the others' replies unrecorded (their revisions would be stale).
    results = await asyncio.gather(*calls, return_exceptions=True)
    for result in results:
        if isinstance(result, BaseException):
            raise result
    return cast(list[T], results)


def _append(path: Path, lines: list[str]) -> None:
    with path.open("a") as out:
        out.write("".join(line + "\n" for line in lines))
