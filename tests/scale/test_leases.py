"""Slot ownership by leases on a real nats-server: an even split, takeover when a worker
dies, rebalancing when one joins, self-fencing when one stalls, recovery after the broker
restarts, leases kept on an event loop starved by ingest, and, replayed from every worker's
own/drop log, never two owners at once."""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Protocol

import pytest
from nats.aio.client import Client
from nats.js.errors import BadRequestError, KeyNotFoundError, KeyWrongLastSequenceError

from kybercore.scale import leases as leases_module
from kybercore.scale.broker import LocalServer, connect
from kybercore.scale.buckets import bucket_keys
from kybercore.scale.leases import FENCE_AT, SLOTS_BUCKET, Leases, _wrong_last
from kybercore.scale.slots import slot_key
from tests.helpers import wait_for
from tests.scale.replay import no_overlap

SLOTS = 16
TTL = 3.0
# Takeover is due TTL + TTL/3 after a worker's last renewal (~4 s): 5× slack.
TAKEOVER_BOUND = 5 * (TTL + TTL / 3)

TURN = 0.015
"""Seconds each turn of a starved event loop costs (ingest at 20,000 updates a second): a
KV call waits for about 7 turns, a renewal round of 32 slots one after another 3.4 s."""


class Start(Protocol):
    def __call__(
        self, name: str, slots: int = SLOTS, site: str = "", ttl: float = TTL
    ) -> Awaitable[Leases]: ...


@pytest.fixture
async def workers(nats_server: LocalServer, tmp_path: Path) -> AsyncIterator[Start]:
    started: list[tuple[Leases, Client]] = []

    async def start(name: str, slots: int = SLOTS, site: str = "", ttl: float = TTL) -> Leases:
        nc = await connect(nats_server.url, name)
        leases = Leases(
            nc, name, url=nats_server.url, slots=slots, ttl=ttl, site=site,
            log_path=tmp_path / f"{name}.log",
        )  # fmt: skip
        await leases.start()
        started.append((leases, nc))
        return leases

    yield start
    for leases, nc in started:
        async with asyncio.timeout(15):  # a broker gone for good must not hang the suite
            await leases.stop(release=False)
            await nc.close()


async def until(what: str, predicate: Callable[[], bool], timeout: float = TAKEOVER_BOUND) -> float:
    """Wait for ``predicate``; the seconds it took."""
    began = time.monotonic()
    while not predicate():
        if time.monotonic() - began > timeout:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        await asyncio.sleep(0.05)  # poll the in-process state, deadline above
    return time.monotonic() - began


async def test_two_workers_split_evenly_and_a_third_rebalances(
    workers: Start, tmp_path: Path
) -> None:
    w1 = await workers("w1")
    await until("w1 owns every slot", lambda: len(w1.owned()) == SLOTS)
    w2 = await workers("w2")
    took = await until("8/8", lambda: len(w1.owned()) == len(w2.owned()) == SLOTS // 2)
    print(f"rebalanced to 8/8 in {took:.1f} s")
    w3 = await workers("w3")
    # Shares are rounded up (ceil(16/3) = 6): the newcomer gets what the others release.
    await until(
        "three owners, none above its share",
        lambda: (
            min(len(w.owned()) for w in (w1, w2, w3)) >= SLOTS - 2 * 6
            and max(len(w.owned()) for w in (w1, w2, w3)) <= 6
        ),
    )
    assert set(w1.owned()) | set(w2.owned()) | set(w3.owned()) == set(range(SLOTS))
    for w in (w1, w2, w3):
        await w.flush_log()
    no_overlap(sorted(tmp_path.glob("w*.log")))


async def test_a_worker_given_another_ttl_fences_by_the_buckets(
    workers: Start, caplog: pytest.LogCaptureFixture
) -> None:
    # Its leases expire at the bucket's TTL: fencing by a longer one of its own would let
    # a peer take a slot it still acts for. (It used to stop at start: JetStream refuses
    # to create a bucket again with another TTL.)
    w1 = await workers("w1")
    w2 = await workers("w2", ttl=TTL * 2)
    assert w2.ttl == TTL
    assert "the kc_slots bucket's leases last 3 s (this process was given 6 s)" in caplog.text
    await until("8/8", lambda: len(w1.owned()) == len(w2.owned()) == SLOTS // 2)


async def test_workers_started_together_take_their_shares_at_once(
    workers: Start, tmp_path: Path
) -> None:
    # Each announces itself and waits a round before claiming: neither takes every slot
    # (and every printer's connection) only to hand half back.
    # Started concurrently: one after the other, the second's connect and bucket lookups
    # outlasted the first's round on a busy machine.
    w1, w2 = await asyncio.gather(workers("w1"), workers("w2"))
    await until("8/8", lambda: len(w1.owned()) == len(w2.owned()) == SLOTS // 2)
    for w in (w1, w2):
        await w.flush_log()
    logs = [line for path in tmp_path.glob("w*.log") for line in path.read_text().splitlines()]
    assert len(logs) == SLOTS
    assert all('"own"' in line for line in logs)


async def test_each_site_shares_its_own_slots_among_its_own_workers(
    workers: Start, nats_server: LocalServer, tmp_path: Path
) -> None:
    # One worker of the default site, two of site "lab-b": the former holds every default
    # slot (not half: the other site's workers do not count toward its share), the latter
    # split lab-b's.
    home = await workers("home")
    b1, b2 = await workers("b1", site="lab-b"), await workers("b2", site="lab-b")
    await until(
        "16 and 8/8",
        lambda: len(home.owned()) == SLOTS and len(b1.owned()) == len(b2.owned()) == SLOTS // 2,
    )
    assert set(b1.owned()) | set(b2.owned()) == set(range(SLOTS))
    nc = await connect(nats_server.url, "reader")
    try:
        keys = set(await bucket_keys(nc.jetstream(), SLOTS_BUCKET))
    finally:
        await nc.close()
    assert keys == {slot_key(n) for n in range(SLOTS)} | {f"lab-b.s{n}" for n in range(SLOTS)}
    # A lab-b worker dying is taken over by lab-b's other one, never by the default site's.
    await b1.stop(release=False)
    await until("b2 owns every lab-b slot", lambda: len(b2.owned()) == SLOTS)
    assert len(home.owned()) == SLOTS
    for w in (home, b2):
        await w.flush_log()
    no_overlap(sorted(tmp_path.glob("*.log")))


async def test_a_dead_workers_slots_are_taken_over(workers: Start, tmp_path: Path) -> None:
    w1, w2 = await workers("w1"), await workers("w2")
    await until("8/8", lambda: len(w1.owned()) == len(w2.owned()) == SLOTS // 2)
    lost = set(w1.owned())
    await w1.stop(release=False)  # as a kill: its keys stay until they expire
    took = await until("w2 owns every slot", lambda: len(w2.owned()) == SLOTS)
    print(f"takeover in {took:.1f} s (TTL {TTL:g} s)")
    assert lost <= set(w2.owned())
    await w2.flush_log()
    no_overlap(sorted(tmp_path.glob("w*.log")))


async def test_a_stalled_worker_fences_itself_before_anyone_takes_over(
    workers: Start, tmp_path: Path
) -> None:
    w1, w2 = await workers("w1"), await workers("w2")
    await until("8/8", lambda: len(w1.owned()) == len(w2.owned()) == SLOTS // 2)
    stalled = set(w1.owned())
    assert w1._task is not None
    w1._task.cancel()  # a paused process: no renewals, the slots still held
    # Fencing before the takeover is what matters; the replay below proves the order.
    await until("w1 fenced", lambda: not w1.owned(), timeout=5 * FENCE_AT * TTL)
    await until("w2 took w1's slots", lambda: stalled <= set(w2.owned()))
    for w in (w1, w2):
        await w.flush_log()
    no_overlap(sorted(tmp_path.glob("w*.log")))


async def test_ownership_comes_back_after_the_broker_restarts(
    workers: Start, nats_server: LocalServer, tmp_path: Path
) -> None:
    w1, w2 = await workers("w1"), await workers("w2")
    await until("8/8", lambda: len(w1.owned()) == len(w2.owned()) == SLOTS // 2)
    port = nats_server.port
    nats_server.stop()
    await until("everything fenced", lambda: not w1.owned() and not w2.owned())
    nats_server.start(port=port)  # same port and data: clients reconnect by themselves
    await until(
        "every slot owned again",
        lambda: set(w1.owned()) | set(w2.owned()) == set(range(SLOTS)),
        timeout=5 * (TTL + 5),
    )
    for w in (w1, w2):
        await w.flush_log()
    no_overlap(sorted(tmp_path.glob("w*.log")))


async def test_a_claim_answered_after_the_peers_lease_expired_skips_only_that_slot(
    workers: Start, nats_server: LocalServer
) -> None:
    # nats-py's create, when its compare-and-set fails, reads the key back to tell a live
    # key from a deleted one; a lease that expires in between (a starved loop) makes that
    # read raise "key not found". It must cost that slot this round, not the whole round.
    w1 = await workers("w1")
    assert w1._task is not None
    assert w1._kv is not None
    w1._task.cancel()  # rounds by hand
    peer = await connect(nats_server.url, "peer")
    try:
        js = peer.jetstream()
        slots = await js.key_value(SLOTS_BUCKET)
        contested = slot_key(0)
        real_update = w1._kv._update

        async def late_reply(key: str, value: bytes, last: int | None = None, **kw: object) -> int:
            if key != contested or last:
                return await real_update(key, value, last=last, **kw)  # type: ignore[arg-type]
            await slots.create(key, b'{"w": "peer", "epoch": 0}')  # the peer gets there first
            try:
                return await real_update(key, value, last=last, **kw)  # type: ignore[arg-type]
            except KeyWrongLastSequenceError:
                # ...and its lease runs out before this reply is read. Gone as by its TTL,
                # without waiting for it: a purge of the stream's subject leaves no tombstone.
                await js.purge_stream(f"KV_{SLOTS_BUCKET}", subject=f"$KV.{SLOTS_BUCKET}.{key}")
                raise

        w1._kv._update = late_reply  # type: ignore[method-assign]
        await w1.round()
        assert set(w1.owned()) == set(range(1, SLOTS))
        w1._kv._update = real_update  # type: ignore[method-assign]
        await w1.round()  # free again: taken
        assert set(w1.owned()) == set(range(SLOTS))
    finally:
        await peer.close()


@asynccontextmanager
async def starved_loop() -> AsyncIterator[None]:
    """Every turn of the event loop costs ``TURN`` seconds while inside."""

    async def hog() -> None:
        while True:
            time.sleep(TURN)  # blocks the loop on purpose: the stand-in for ingest's work
            await asyncio.sleep(0)

    task = asyncio.create_task(hog())
    try:
        yield
    finally:
        task.cancel()


def rounds_of(leases: Leases, method: str = "round") -> list[float]:
    """The monotonic() ends of ``leases``' rounds (or renewals) from now on."""
    ended: list[float] = []
    real = getattr(leases, method)

    async def counted(*args: object) -> None:
        await real(*args)
        ended.append(time.monotonic())

    setattr(leases, method, counted)
    return ended


def drops(paths: list[Path]) -> list[str]:
    return [line for path in paths for line in path.read_text().splitlines() if '"drop"' in line]


async def test_a_starved_loop_renews_every_lease_in_time(workers: Start, tmp_path: Path) -> None:
    # 64 slots, as deployed: 32 renewals a round. Sent one after another, each waiting for
    # its reply, a round outlasted the fence and every lease was dropped and claimed again.
    w1, w2 = await workers("w1", slots=64), await workers("w2", slots=64)
    await until("32/32", lambda: len(w1.owned()) == len(w2.owned()) == 32)
    for w in (w1, w2):
        await w.flush_log()
    logs = sorted(tmp_path.glob("w*.log"))
    before = drops(logs)  # w1 started alone, took every slot and released half to w2
    ended = [rounds_of(w1), rounds_of(w2)]

    def three_rounds_each() -> bool:
        w1.owned(), w2.owned()  # fences what is late, as a worker's reconcile does
        return min(len(e) for e in ended) >= 3

    async with starved_loop():
        await until("three starved rounds each", three_rounds_each, timeout=3 * TAKEOVER_BOUND)
    assert len(w1.owned()) == len(w2.owned()) == 32
    for w in (w1, w2):
        await w.flush_log()
    assert drops(logs) == before


async def test_a_starved_loop_takes_a_dead_peers_slots_and_keeps_its_own(
    workers: Start, tmp_path: Path
) -> None:
    # Claims run after the renewals and before the next round's: 32 creates one after
    # another delayed those renewals past the fence.
    w1, w2 = await workers("w1", slots=64), await workers("w2", slots=64)
    await until("32/32", lambda: len(w1.owned()) == len(w2.owned()) == 32)
    await w1.flush_log()
    log = tmp_path / "w1.log"
    before = drops([log])
    async with starved_loop():
        await w2.stop(release=False)  # as a kill: its keys stay until they expire
        await until("w1 owns every slot", lambda: len(w1.owned()) == 64, timeout=3 * TAKEOVER_BOUND)
    await w1.flush_log()
    assert drops([log]) == before
    no_overlap(sorted(tmp_path.glob("w*.log")))


async def test_a_released_slot_is_let_go_before_its_delete_is_answered(
    workers: Start, tmp_path: Path
) -> None:
    # A peer may create the key as soon as the delete lands; on a starved loop the delete's
    # reply comes turns later, and until then the releasing worker still acted for it.
    w1 = await workers("w1")
    await until("w1 owns every slot", lambda: len(w1.owned()) == SLOTS)
    assert w1._kv is not None
    real_delete = w1._kv.delete
    peer_owned: list[bool] = []

    async def late_reply(key: str, last: int | None = None, **kw: object) -> bool:
        deleted = await real_delete(key, last=last, **kw)  # type: ignore[arg-type]
        slot = int(key.removeprefix("s"))
        if not peer_owned:  # the first release: its reply is read once w2 owns the slot
            await until(f"w2 owns slot {slot}", lambda: slot in w2.owned())
            peer_owned.append(slot in w1.owned())
        return deleted

    w1._kv.delete = late_reply  # type: ignore[method-assign]
    w2 = await workers("w2")
    await until("8/8", lambda: len(w1.owned()) == len(w2.owned()) == SLOTS // 2)
    assert peer_owned == [False]  # w1 no longer acted for it
    for w in (w1, w2):
        await w.flush_log()
    no_overlap(sorted(tmp_path.glob("w*.log")))


async def test_a_slot_fenced_during_a_release_does_not_fail_the_round(
    workers: Start, caplog: pytest.LogCaptureFixture
) -> None:
    # The worker asks for its slots' epochs at any time, which fences the stale ones; one
    # fenced while an earlier release's delete was awaited was then looked up and failed
    # the whole round (KeyError: the slot), seen at N = 5,000.
    w1 = await workers("w1")
    await until("w1 owns every slot", lambda: len(w1.owned()) == SLOTS)
    assert w1._kv is not None
    real_delete = w1._kv.delete
    fenced: list[int] = []

    async def fence_another(key: str, last: int | None = None, **kw: object) -> bool:
        if not fenced:  # the first release: the last slot to release goes stale meanwhile
            slot = max(w1._held)
            w1._held[slot].renewed_sent -= 2 * w1.ttl
            assert w1.epoch(slot) is None
            fenced.append(slot)
        return await real_delete(key, last=last, **kw)  # type: ignore[arg-type]

    w1._kv.delete = fence_another  # type: ignore[method-assign]
    with caplog.at_level("WARNING", logger="kybercore.scale.leases"):
        w2 = await workers("w2")
        await until("8/8", lambda: len(w1.owned()) == len(w2.owned()) == SLOTS // 2)
    assert fenced
    assert "lease round failed" not in caplog.text


async def test_a_slow_count_of_the_workers_does_not_delay_the_renewals(
    workers: Start, tmp_path: Path
) -> None:
    # Counting the workers is a broker round trip, late on a starved loop (it took several
    # when it was an ephemeral consumer). Renewed after it in the same round, every lease
    # was fenced.
    w1, w2 = await workers("w1"), await workers("w2")
    await until("8/8", lambda: len(w1.owned()) == len(w2.owned()) == SLOTS // 2)
    await w1.flush_log()
    log = tmp_path / "w1.log"
    before = drops([log])
    count = w1.live_workers
    renewed = rounds_of(w1, "renew")

    async def slow_count() -> int:
        # A FAKE slow broker reply: the count answers only after 4 more renewals, TTL/3
        # apart, so it outlasts the fence (0.8·TTL).
        before = len(renewed)
        await wait_for(lambda: len(renewed) >= before + 4, TAKEOVER_BOUND, "renewals")
        return await count()

    w1.live_workers = slow_count  # type: ignore[method-assign]
    ended = rounds_of(w1)

    def two_slow_rounds() -> bool:
        w1.owned()  # fences what is late, as a worker's reconcile does
        return len(ended) >= 2

    await until("two slow rounds", two_slow_rounds, timeout=3 * TAKEOVER_BOUND)
    assert len(w1.owned()) == SLOTS // 2
    await w1.flush_log()
    assert drops([log]) == before


def busy(seconds: float) -> None:
    """Hold this thread (the event loop's) and the GIL as ingest at full tilt does: nothing
    on the loop runs meanwhile; other threads get the GIL only at its switch interval."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pass


async def test_a_loop_blocked_past_the_ttl_keeps_its_leases(workers: Start, tmp_path: Path) -> None:
    # Renewed on the loop, every lease expired meanwhile: both workers fenced and claimed
    # everything again when it came back. Renewed on their own threads, none is lost.
    w1, w2 = await workers("w1"), await workers("w2")
    await until("8/8", lambda: len(w1.owned()) == len(w2.owned()) == SLOTS // 2)
    held = (set(w1.owned()), set(w2.owned()))
    logs = sorted(tmp_path.glob("w*.log"))
    for w in (w1, w2):
        await w.flush_log()
    before = drops(logs)
    busy(2 * TTL)
    assert (set(w1.owned()), set(w2.owned())) == held  # renewed in time: not fenced
    ended = rounds_of(w1)
    await until("two more rounds", lambda: len(ended) >= 2)
    for w in (w1, w2):
        await w.flush_log()
    assert drops(logs) == before
    assert (set(w1.owned()), set(w2.owned())) == held


async def test_a_hung_loop_lets_its_leases_expire(
    workers: Start, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A loop that does not turn for LOOP_GRACE TTLs is hung, not late: its renewals stop,
    # so that its printers are not held for ever (one TTL here, five when deployed).
    monkeypatch.setattr(leases_module, "LOOP_GRACE", 1.0)
    w1 = await workers("w1")
    await until("w1 owns every slot", lambda: len(w1.owned()) == SLOTS)
    busy(4 * TTL)  # renewals stop after 1 TTL; the keys expire 1 TTL after the last one
    assert not w1.owned()  # fenced: its last renewal is too old
    await w1.flush_log()
    dropped = drops([tmp_path / "w1.log"])
    assert len(dropped) == SLOTS, dropped
    assert all('"fence"' in line for line in dropped)


def test_a_release_on_a_revision_moved_on_is_someone_elses_key_not_a_failed_round() -> None:
    # nats-py raises it from delete as a bare BadRequestError (from update, as
    # KeyWrongLastSequenceError): it failed every round that released a slot.
    moved = BadRequestError(code=400, err_code=10071, description="wrong last sequence: 41")
    assert _wrong_last(moved)
    assert _wrong_last(KeyNotFoundError())
    assert not _wrong_last(BadRequestError(code=400, err_code=10058, description="other"))


async def write_over(
    nats_server: LocalServer, bucket: str, key: str, value: bytes | None = None
) -> int:
    """Store ``value`` (None: what the key holds) on the key's current revision, as a
    renewal would: one its holder never hears answered. Returns the revision written."""
    nc = await connect(nats_server.url, "test")
    try:
        kv = await nc.jetstream().key_value(bucket)
        while True:  # the holder's own renewals move the revision too: retry on theirs
            entry = await kv.get(key)
            with contextlib.suppress(KeyWrongLastSequenceError):
                return await kv.update(key, value or entry.value or b"", last=entry.revision)
    finally:
        await nc.close()


def lease(worker: str, epoch: int) -> bytes:
    """A slot's lease value as ``worker`` writes it."""
    return json.dumps({"w": worker, "epoch": epoch}).encode()


async def test_a_renewal_stored_but_never_answered_keeps_the_slot(
    workers: Start, nats_server: LocalServer, tmp_path: Path
) -> None:
    # Its reply lost, the worker's next compare-and-set named a revision one behind and the
    # slot was dropped as someone else's, though the key was still this lease.
    w1 = await workers("w1")
    await until("w1 owns every slot", lambda: len(w1.owned()) == SLOTS)
    epoch = w1.owned()[0]
    await write_over(nats_server, SLOTS_BUCKET, slot_key(0), lease("w1", epoch))
    renewed = rounds_of(w1, "renew")
    await until("two renewals", lambda: len(renewed) >= 2)
    await w1.flush_log()
    assert drops([tmp_path / "w1.log"]) == []
    assert w1.owned()[0] == epoch


async def test_a_renewal_that_finds_another_workers_lease_drops_the_slot(
    workers: Start, nats_server: LocalServer, tmp_path: Path
) -> None:
    w1 = await workers("w1")
    await until("w1 owns every slot", lambda: len(w1.owned()) == SLOTS)
    await write_over(nats_server, SLOTS_BUCKET, slot_key(0), lease("w9", w1.owned()[0]))
    await until("slot 0 lost", lambda: 0 not in w1.owned())
    await w1.flush_log()
    assert [json.loads(line)["why"] for line in drops([tmp_path / "w1.log"])] == ["lost"]
