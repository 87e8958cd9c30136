"""Which worker owns which slot: leases in a JetStream key-value bucket.

Every TTL/3 a worker renews each slot it owns, all at once, with a compare-and-set on the
key's revision. A failure means someone else holds it now, and the slot is dropped at once,
unless the key still holds this very lease: a renewal stored but not answered.
The renewals run on a thread of their own, with a connection of their own
(:mod:`.renewer`), apart from the worker's event loop and the rounds that share the slots
out: on a loop starved by ingest, the renewals ran late past the fence, and every lease was
dropped and claimed again.

Every TTL/3, too, a round:

1. writes its heartbeat into ``kc_workers`` (a bucket whose keys expire after the TTL), and
   counts the live workers of its site: its fair share is ``ceil(S / workers)``;
2. releases the slots above its share (a delete, also compare-and-set);
3. creates free slots (``create`` succeeds only if the key is absent) up to its share: it
   reads the other slots' keys at once, and creates as many free ones at once as it lacks.

A slot whose last successful renewal was *sent* more than 0.8·TTL ago is fenced: the worker
stops acting for it before the key can expire and be created by another worker (a full TTL
after that renewal). A paused process cannot fence itself; the revision at create is the
slot's epoch, carried on everything the owner publishes, so its late messages are ignored.

Every gain and loss is written as a JSON line (``own``/``drop``) so that ownership can be
replayed: per slot, intervals of different workers must never overlap.

A worker started for a site (:mod:`.slots`) holds that site's slots only (keys
``<site>.s<n>``), shared among that site's workers.
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
from nats.js.errors import (
    BadRequestError,
    KeyNotFoundError,
    KeyWrongLastSequenceError,
)
from nats.js.kv import KeyValue

from kybercore.aio import cancel_and_wait
from kybercore.scale.broker import jetstream
from kybercore.scale.buckets import bucket_keys, lease_bucket, wrong_revision
from kybercore.scale.renewer import LOOP_GRACE, Renewer
from kybercore.scale.slots import DEFAULT_SITE, fair_share, site_token, slot_key

log = logging.getLogger(__name__)

SLOTS_BUCKET: Final = "kc_slots"
WORKERS_BUCKET: Final = "kc_workers"
FENCE_AT: Final = 0.8
"""Of the TTL: a slot not renewed for this long is no longer acted on."""
RENEWAL_POLL: Final = 0.005
"""Seconds between looks at a renewal on its way, before a release."""
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
    renewing: bool = False
    """A renewal of it is on its way (the renewals' thread): a release waits for its
    revision."""


Change = Callable[[int, int | None, str], None]
"""Told ``(slot, epoch, "")`` when a slot is gained, ``(slot, None, why)`` when it is lost:
``why`` is ``lost`` (another worker has it), ``fence``, ``release`` (handed to a peer for
a fair share) or ``stop``."""


class Leases:
    """One worker's side of slot ownership; see the module docstring."""

    def __init__(
        self, nc: Client, worker: str, *, url: str, slots: int, ttl: float,
        site: str = DEFAULT_SITE, log_path: Path | None = None,
        on_change: Change | None = None, local: bool = False,
    ) -> None:  # fmt: skip
        """``url``: the broker's, for the renewals' own connection; ``site``: whose slots;
        ``local``: the leases are kept in the connected server's own JetStream, a site's
        leaf node's, so a cut from the hub leaves them held (README "Sites")."""
        self._nc = nc
        self._url = url
        self.worker = worker
        self.site = site
        self._heartbeat = f"{site_token(site)}.{worker}"
        """This worker's key in ``kc_workers``: its site first, to count a site's workers."""
        self.slots = slots
        self.ttl = ttl
        self._log_path = log_path
        self._on_change = on_change
        self._held: dict[int, Held] = {}
        self._local = local
        self._js = jetstream(nc, local=local)
        self._kv: KeyValue | None = None
        self._workers: KeyValue | None = None
        self._task: asyncio.Task[None] | None = None
        self._pending: list[str] = []
        self._flushing = asyncio.Lock()
        self._home: asyncio.AbstractEventLoop | None = None
        """The worker's loop: what the renewals' thread learns is handed back to it."""
        self._turned = time.monotonic()
        """monotonic() when the worker's loop last turned (see :mod:`.renewer`)."""

    async def start(self) -> None:
        """Open (or create) the buckets and start the renewal loop. The slots bucket's TTL
        is the one to fence by: a worker given another one follows it."""
        self._home = asyncio.get_running_loop()
        self._kv, self.ttl = await lease_bucket(self._js, SLOTS_BUCKET, self.ttl, self.worker)
        self._workers, _ = await lease_bucket(self._js, WORKERS_BUCKET, self.ttl, self.worker)
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
                    await self._release(slot, held)
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
            await self._workers.put(self._heartbeat, b"1")
            await asyncio.sleep(self.ttl / 3)
        # Stopped with this task: cancelling it (a stop, or a test standing in for a paused
        # process) stops the renewals too. ``round`` and ``renew`` are looked up at each call
        # (a test counts them by wrapping them).
        renewer = Renewer(
            self._url, f"{self.worker}-leases", SLOTS_BUCKET, self.ttl / 3,
            lambda kv: self.renew(kv), self._loop_alive, local=self._local,
        )  # fmt: skip
        ticking = asyncio.create_task(self._tick())
        try:
            await renewer.start()
            await self._rounds()
        finally:
            await cancel_and_wait(ticking)
            await renewer.stop()

    async def _tick(self) -> None:
        while True:
            self._turned = time.monotonic()
            await asyncio.sleep(self.ttl / 10)

    def _loop_alive(self) -> bool:
        return time.monotonic() - self._turned < LOOP_GRACE * self.ttl

    async def _rounds(self) -> None:
        while True:
            started = time.monotonic()
            try:
                await self.round()
            except Exception as exc:  # the broker away: fencing covers it; try again
                log.warning("%s: lease round failed: %s", self.worker, exc)
            self.owned()  # fence what is too old now
            await self.flush_log()
            await asyncio.sleep(max(0.0, self.ttl / 3 - (time.monotonic() - started)))

    async def renew(self, kv: KeyValue) -> None:
        """Renew every slot held, all at once, through ``kv`` (the renewals' thread's own):
        32 renewals in turn outlast the fence on a slow connection."""
        await _all(self._renew(kv, slot, held) for slot, held in list(self._held.items()))

    async def round(self) -> None:
        """One heartbeat, release and claim pass."""
        assert self._kv is not None
        assert self._workers is not None
        await self._workers.put(self._heartbeat, b"1")
        share = fair_share(self.slots, await self.live_workers())
        self.owned()
        for slot in sorted(self._held)[share:]:
            # Let go before the delete is sent: a peer may create the key as soon as the
            # delete lands, long before its reply is read on a starved loop.
            held = self._held.get(slot)
            if held is None:  # fenced (the worker asked for its epoch) during a delete
                continue
            self._drop(slot, "release")
            await self._release(slot, held)
        await self._claim(share)

    async def live_workers(self) -> int:
        """How many workers of this site have a heartbeat in ``kc_workers`` now.
        Heartbeats are never deleted, they expire: every key left is a live worker."""
        site = self._heartbeat.split(".", 1)[0] + "."
        return len(await bucket_keys(self._js, WORKERS_BUCKET, site))

    async def _release(self, slot: int, held: Held) -> None:
        assert self._kv is not None
        # A renewal sent just before the drop would make this delete's revision stale, and
        # the key would then stay, unrenewed, for a TTL with nobody acting for its printers.
        # It takes milliseconds; its thread sets the revision first, then the flag (a plain
        # flag: an asyncio.Event cannot be set from another thread at once).
        while held.renewing:  # noqa: ASYNC110
            await asyncio.sleep(RENEWAL_POLL)
        try:
            await self._kv.delete(self._key(slot), last=held.revision)
        except (KeyNotFoundError, BadRequestError) as exc:
            if not _wrong_last(exc):
                raise

    async def _renew(self, kv: KeyValue, slot: int, held: Held) -> None:
        # On the renewals' thread. The flag goes up before the check, so a release on the
        # worker's loop (drop, then wait for the flag) never deletes with a stale revision.
        held.renewing = True
        try:
            if self._held.get(slot) is not held:
                return  # released or dropped meanwhile: its key is not renewed any more
            sent = time.monotonic()
            value = self._value(held.epoch)
            held.revision = await kv.update(self._key(slot), value, last=held.revision)
            held.renewed_sent = sent
        except (KeyWrongLastSequenceError, KeyNotFoundError):
            if await self._still_mine(kv, slot, held):
                return
            assert self._home is not None
            self._home.call_soon_threadsafe(self._lost, slot, held)
        finally:
            held.renewing = False

    async def _still_mine(self, kv: KeyValue, slot: int, held: Held) -> bool:
        # A renewal stored by the broker whose reply never came back leaves the revision
        # here one behind: the key is still this lease (this worker's name and epoch, which
        # no other worker writes), so the next compare-and-set takes its revision and the
        # slot is kept. ``renewed_sent`` stays as it was: fencing by it remains on the safe
        # side of the key's expiry. Anything else (gone, or another's) is a loss.
        key = self._key(slot)
        try:
            entry = await kv.get(key)
        except KeyNotFoundError:
            log.warning("%s: renewing %s: the key is gone (expired)", self.worker, key)
            return False
        # (A key still as created, epoch 0, would not have refused the compare-and-set.)
        if entry.value != self._value(held.epoch):
            log.warning("%s: renewing %s: the key holds %r now", self.worker, key, entry.value)
            return False
        assert entry.revision is not None
        log.warning(
            "%s: renewing %s: a renewal's reply went missing (revision %s, not %s): kept",
            self.worker, key, entry.revision, held.revision,
        )  # fmt: skip
        held.revision = entry.revision
        return True

    def _lost(self, slot: int, held: Held) -> None:
        # epoch() first: a slot whose renewals stopped (a paused process) is fenced as of
        # 0.8·TTL after its last one, not "lost" only now that the failure is heard.
        if self._held.get(slot) is held and self.epoch(slot) is not None:
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
            await self._kv.get(self._key(slot))
        except KeyNotFoundError:  # never written, expired, or deleted
            return False
        return True

    async def _create(self, slot: int) -> None:
        assert self._kv is not None
        sent = time.monotonic()
        try:
            revision = await self._kv.create(self._key(slot), self._value(0))
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

    def _key(self, slot: int) -> str:
        return slot_key(slot, self.site)

    def _value(self, epoch: int) -> bytes:
        return json.dumps({"w": self.worker, "epoch": epoch}).encode()

    def _drop(self, slot: int, why: str, at: float | None = None) -> None:
        held = self._held.pop(slot, None)
        if held is None:
            return
        log.info("%s: slot %s dropped (%s)", self.worker, self._key(slot), why)
        self._write("drop", slot, held.epoch, why=why, at=at)
        if self._on_change:
            self._on_change(slot, None, why)

    def _write(
        self, event: str, slot: int, epoch: int, why: str = "", at: float | None = None
    ) -> None:
        # "at": when it took effect; a fence takes effect 0.8·TTL after the last renewal,
        # however late it is noticed. Wall time lets logs of several processes be merged.
        wall = time.time() - (time.monotonic() - at) if at is not None else time.time()
        line = {
            "ev": event, "slot": slot, "key": self._key(slot), "epoch": epoch,
            "worker": self.worker, "why": why,
        }  # fmt: skip
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


def _wrong_last(exc: Exception) -> bool:
    """The key is gone, or holds another revision (someone else's lease now): nats-py
    raises the latter from ``delete`` as a bare BadRequestError."""
    return isinstance(exc, KeyNotFoundError) or wrong_revision(exc)


def _append(path: Path, lines: list[str]) -> None:
    with path.open("a") as out:
        out.write("".join(line + "\n" for line in lines))
