"""The dispatcher role on a real nats-server: one holder at a time, a takeover when the
holder stops or goes silent, and a holder that cannot renew fences itself first."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass, field

import pytest
from nats.aio.client import Client
from nats.js.errors import KeyNotFoundError

from kybercore.scale.broker import LocalServer, connect
from kybercore.scale.leader import ROLES_BUCKET, Leadership
from tests.helpers import wait_for
from tests.scale.test_leases import TAKEOVER_BOUND, TTL, until, write_over


@dataclass
class Contender:
    """A front's claim, with what its hooks saw."""

    leadership: Leadership
    nc: Client
    events: list[str] = field(default_factory=list)
    fail_gain: bool = False

    @property
    def running(self) -> bool:
        """Whether its work is started (gained and not lost since)."""
        return bool(self.events) and self.events[-1] == "gain"


Start = Callable[[str], Awaitable[Contender]]


@pytest.fixture
async def contenders(nats_server: LocalServer) -> AsyncIterator[Start]:
    started: list[Contender] = []

    async def start(name: str) -> Contender:
        nc = await connect(nats_server.url, name)

        async def gain() -> None:
            if contender.fail_gain:
                raise RuntimeError("the database is away")
            contender.events.append("gain")

        async def loss() -> None:
            contender.events.append("loss")

        leadership = Leadership(nc, "dispatcher", name, ttl=TTL, on_gain=gain, on_loss=loss)
        contender = Contender(leadership, nc)
        await leadership.start()
        started.append(contender)
        return contender

    yield start
    for contender in started:
        async with asyncio.timeout(15):
            await contender.leadership.stop()
            await contender.nc.close()


async def test_one_holder_at_a_time_and_a_takeover_when_it_stops(contenders: Start) -> None:
    a = await contenders("front-a")
    b = await contenders("front-b")
    await until("one holder", lambda: a.running or b.running)
    holder, other = (a, b) if a.running else (b, a)
    # Several rounds later, still exactly one: the other's create keeps failing.
    rounds = 0

    def several_rounds() -> bool:
        nonlocal rounds
        assert not (a.running and b.running), "two dispatchers at once"
        rounds += 1
        return rounds > 60  # 60 polls of 50 ms: about one TTL

    await until("a TTL with one holder", several_rounds)
    assert other.events == []
    await holder.leadership.stop()
    assert holder.events == ["gain", "loss"]
    await until("the takeover", lambda: other.running)  # released: at the next round


async def test_a_holder_that_cannot_renew_fences_itself_before_another_takes_over(
    contenders: Start,
) -> None:
    a = await contenders("front-a")
    await until("a holds the role", lambda: a.running)
    b = await contenders("front-b")
    await a.nc.close()  # a is cut off from the broker: its renewals fail
    fenced = await until("a fences itself", lambda: not a.running)
    assert fenced <= TAKEOVER_BOUND
    assert not b.running, "a must have stopped before the key could expire"
    await until("b takes over after the TTL", lambda: b.running)
    assert a.events == ["gain", "loss"]
    assert b.events == ["gain"]


async def test_a_holder_that_fails_to_start_hands_the_role_on(contenders: Start) -> None:
    a = await contenders("front-a")
    a.fail_gain = True
    await until("a tried and gave up", lambda: a.events == ["loss"])
    a.fail_gain = False
    b = await contenders("front-b")
    await until("someone holds it", lambda: a.running or b.running)


async def test_a_contender_given_another_ttl_fences_by_the_buckets(
    contenders: Start, nats_server: LocalServer
) -> None:
    a = await contenders("front-a")
    nc = await connect(nats_server.url, "front-b")

    async def nothing() -> None:
        pass

    b = Leadership(nc, "dispatcher", "front-b", ttl=TTL * 2, on_gain=nothing, on_loss=nothing)
    try:
        await b.start()
        # Fencing by its own longer TTL would let it act after the key expired.
        assert b.ttl == a.leadership.ttl == TTL
    finally:
        await b.stop()
        await nc.close()


async def test_a_renewal_stored_but_never_answered_keeps_the_role(
    contenders: Start, nats_server: LocalServer
) -> None:
    # Its reply lost, the holder's next compare-and-set named a revision one behind and it
    # gave the role up, though the key still held its claim.
    a = await contenders("front-a")
    await until("a holds the role", lambda: a.running)
    written = await write_over(nats_server, ROLES_BUCKET, "dispatcher")
    nc = await connect(nats_server.url, "test")
    try:
        kv = await nc.jetstream().key_value(ROLES_BUCKET)

        async def renewed() -> bool:
            with contextlib.suppress(KeyNotFoundError):  # expired: the role was given up
                return ((await kv.get("dispatcher")).revision or 0) > written
            return False

        await wait_for(renewed, TAKEOVER_BOUND, "a renewal after it")
    finally:
        await nc.close()
    assert a.events == ["gain"]


async def test_a_renewal_that_finds_another_claim_gives_the_role_up(
    contenders: Start, nats_server: LocalServer
) -> None:
    a = await contenders("front-a")
    await until("a holds the role", lambda: a.running)
    await write_over(nats_server, ROLES_BUCKET, "dispatcher", b'{"holder": "front-a"}')
    await until("a gives the role up", lambda: not a.running)
    assert a.events == ["gain", "loss"]
