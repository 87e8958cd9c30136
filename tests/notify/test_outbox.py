"""The outbox for real: a loopback receiver that fails, goes down and comes back, real
SQLite and PostgreSQL underneath, and a restart in between. Backoffs are hundredths of a
second here; every wait is for a condition."""

from __future__ import annotations

import base64
from collections.abc import AsyncIterator, Callable
from datetime import UTC, datetime

import httpx
import pytest
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.db import open_database
from kybercore.notify.outbox import Outbox, backoff
from kybercore.notify.records import Delivery
from kybercore.notify.rules import ChannelRules
from kybercore.notify.store import NotifyStore
from kybercore.notify.texts import render
from tests.helpers import wait_for
from tests.notify.conftest import add_webhook, fleet_event
from tests.notify.receiver import Received, Receiver

FAST = {"first_retry": 0.05, "max_retry": 0.2}


@pytest.fixture
async def outbox(store: NotifyStore, http: httpx.AsyncClient) -> AsyncIterator[Outbox]:
    """A started outbox with fast retries on the test's store."""
    started = Outbox(store, http, **FAST)
    await started.start()
    yield started
    await started.stop()


def event_ids(requests: list[Received], printer: str | None = None) -> list[str]:
    """The event ids of ``requests``, of one printer's events when ``printer`` is given."""
    return [
        r.headers["x-kybercore-event-id"]
        for r in requests
        if printer is None or (r.json()["printer"] or {}).get("id") == printer
    ]


def attempted(store: NotifyStore, ids: list[int]) -> Callable[[], object]:
    """A condition: every delivery of ``ids`` was tried at least once."""

    async def check() -> bool:
        return all([(await store.delivery(i)).attempts >= 1 for i in ids])

    return check


def all_delivered(store: NotifyStore, count: int) -> Callable[[], object]:
    async def check() -> bool:
        return [d.status for d in await store.deliveries()] == ["delivered"] * count

    return check


async def test_a_receiver_answering_500_then_200_gets_the_event_once(
    store: NotifyStore, outbox: Outbox, receiver: Receiver
) -> None:
    hook = await add_webhook(store, receiver.url())
    receiver.fail_next(1, 500)
    event = fleet_event()
    (delivery,) = await store.record(event, None, {hook.id: "deliver"})
    outbox.wake()

    async def delivered() -> bool:
        return (await store.delivery(delivery)).status == "delivered"

    await wait_for(delivered, what="the delivery after one retry")
    assert [r.status for r in receiver.requests] == [500, 200]
    assert event_ids(receiver.accepted) == [event.id]
    # Both tries carried the same event id: what a receiver dedupes on.
    assert event_ids(receiver.requests) == [event.id, event.id]
    done = await store.delivery(delivery)
    assert (done.attempts, done.response_code) == (2, 200)
    assert done.last_error == "The receiver answered HTTP 500: receiver says no"


async def test_with_the_receiver_down_each_printers_events_arrive_later_in_order_once(
    store: NotifyStore, outbox: Outbox, receiver: Receiver
) -> None:
    hook = await add_webhook(store, receiver.url())
    await receiver.stop()
    events = [fleet_event("print_started", p, filename=f"{p}{n}.gcode")
              for n, p in enumerate("aabab")]  # fmt: skip
    ids = []
    for event in events:
        ids += await store.record(event, None, {hook.id: "deliver"})
        outbox.wake()
    # The first of each printer was tried (and failed) while the receiver was down.
    await wait_for(attempted(store, [ids[0], ids[2]]), what="tries while the receiver is down")
    assert receiver.requests == []
    assert (await store.delivery(ids[0])).last_error.startswith("Could not reach the receiver")
    await receiver.start()
    await wait_for(lambda: len(receiver.accepted) >= 5, what="every event after the restart")
    for printer in "ab":
        assert event_ids(receiver.accepted, printer) == [
            e.id for e in events if e.printer and e.printer.id == printer
        ]
    assert sorted(event_ids(receiver.accepted)) == sorted(e.id for e in events)
    await wait_for(all_delivered(store, 5), what="every delivery marked delivered")


async def test_events_left_undelivered_at_a_restart_are_delivered_after_it(
    database_url: str, http: httpx.AsyncClient, receiver: Receiver
) -> None:
    engine = await open_database(database_url)
    store = NotifyStore(engine)
    first = Outbox(store, http, **FAST)
    await first.start()
    hook = await add_webhook(store, receiver.url())
    await receiver.stop()
    events = [fleet_event("printer_offline", p, was="printing") for p in "abca"]
    ids = [i for e in events for i in await store.record(e, None, {hook.id: "deliver"})]
    first.wake()
    await wait_for(attempted(store, ids[:3]), what="tries before the restart")
    await first.stop()
    await engine.dispose()
    # A new KyberCore: a new engine, store and outbox on the same database; the receiver
    # is back.
    await receiver.start()
    engine = await open_database(database_url)
    try:
        store = NotifyStore(engine)
        second = Outbox(store, http, **FAST)
        await second.start()
        try:
            await wait_for(lambda: len(receiver.accepted) >= 4, what="delivery after restart")
            await wait_for(all_delivered(store, 4), what="every delivery marked delivered")
        finally:
            await second.stop()
    finally:
        await engine.dispose()
    assert sorted(event_ids(receiver.accepted)) == sorted(e.id for e in events)
    assert event_ids(receiver.accepted, "a") == [events[0].id, events[3].id]


async def test_a_send_cut_off_by_a_stop_is_handed_back_and_sent_after_the_restart(
    store: NotifyStore, http: httpx.AsyncClient, receiver: Receiver
) -> None:
    hook = await add_webhook(store, receiver.url())
    receiver.hold()
    first = Outbox(store, http, **FAST, stop_grace=0.1)
    await first.start()
    event = fleet_event()
    (delivery,) = await store.record(event, None, {hook.id: "deliver"})
    first.wake()
    await wait_for(lambda: receiver.held == 1, what="the send to hang")
    await first.stop()
    # Handed back unsent: due now, not after the claim's two minutes.
    cut = await store.delivery(delivery)
    assert (cut.status, cut.attempts) == ("pending", 0)
    assert await store.next_due() <= datetime.now(UTC)
    await receiver.stop()  # answers the hung request (503), then is back
    await receiver.start()
    second = Outbox(store, http, **FAST)
    await second.start()
    try:
        await wait_for(all_delivered(store, 1), what="the delivery after the restart")
    finally:
        await second.stop()
    assert event_ids(receiver.accepted) == [event.id]


async def test_a_delivery_given_up_is_failed_and_no_longer_holds_its_printer_back(
    store: NotifyStore, http: httpx.AsyncClient, receiver: Receiver
) -> None:
    hook = await add_webhook(store, receiver.url())
    doomed, later = fleet_event("print_failed", "a"), fleet_event("print_started", "a")
    receiver.refuse(lambda r: r.headers["x-kybercore-event-id"] == doomed.id)
    outbox = Outbox(store, http, first_retry=0.05, max_retry=0.1, give_up_after=0.6)
    (first,) = await store.record(doomed, None, {hook.id: "deliver"})
    (second,) = await store.record(later, None, {hook.id: "deliver"})
    await outbox.start()
    try:

        async def later_delivered() -> bool:
            return (await store.delivery(second)).status == "delivered"

        await wait_for(later_delivered, what="the later event after the first was given up")
    finally:
        await outbox.stop()
    failed = await store.delivery(first)
    assert failed.status == "failed"
    assert failed.attempts >= 2
    assert failed.last_error == "The receiver answered HTTP 500: receiver says no"
    assert failed.response_code == 500
    # Held back until then: every try of the doomed one came before the later one's.
    order = event_ids(receiver.requests)
    assert order == [doomed.id] * failed.attempts + [later.id]


def test_retries_back_off_exponentially_with_jitter_up_to_the_cap() -> None:
    for attempts, ceiling in [(1, 2.0), (2, 4.0), (3, 8.0), (8, 256.0), (9, 300.0), (30, 300.0)]:
        delays = [backoff(attempts, 2.0, 300.0) for _ in range(50)]
        assert all(ceiling / 2 <= delay <= ceiling for delay in delays), (attempts, delays)
        assert len(set(delays)) > 1  # jittered


async def test_wait_outcome_answers_after_the_first_attempt(
    store: NotifyStore, outbox: Outbox, receiver: Receiver
) -> None:
    hook = await add_webhook(store, receiver.url())
    (ok,) = await store.record(fleet_event("test", None), None, {hook.id: "deliver"})
    outbox.wake()
    done = await outbox.wait_outcome(ok, timeout=10)
    assert (done.status, done.attempts, done.response_code) == ("delivered", 1, 200)
    await receiver.stop()
    (down,) = await store.record(fleet_event("test", None), None, {hook.id: "deliver"})
    outbox.wake()
    tried: Delivery = await outbox.wait_outcome(down, timeout=10)
    assert (tried.status, tried.attempts) == ("pending", 1)
    assert tried.last_error.startswith("Could not reach the receiver")
    assert tried.next_at is not None


async def test_an_apprise_channel_is_delivered_by_the_outbox_with_its_snapshot(
    store: NotifyStore, outbox: Outbox, receiver: Receiver, database: AsyncEngine
) -> None:
    channel = await store.add_channel(
        name="json", kind="apprise", target=f"json://127.0.0.1:{receiver.port}/a",
        secret=None, rules=ChannelRules(language="es"), enabled=True, user="ana",
    )  # fmt: skip
    no_pictures = await store.add_channel(
        name="bare", kind="apprise", target=f"json://127.0.0.1:{receiver.port}/b",
        secret=None, rules=ChannelRules(attach_snapshot=False), enabled=True, user="ana",
    )  # fmt: skip
    event = fleet_event("print_completed", "a", filename="cube.gcode")
    jpeg = b"\xff\xd8\xff" + b"x" * 1000
    await store.record(event, jpeg, {channel.id: "deliver", no_pictures.id: "deliver"})
    outbox.wake()
    await wait_for(lambda: len(receiver.accepted) == 2, what="both Apprise deliveries")
    by_path = {r.path: r.json() for r in receiver.accepted}
    title, body = render(event, "es")
    assert (by_path["/a"]["title"], by_path["/a"]["message"]) == (title, body)
    assert base64.b64decode(by_path["/a"]["attachments"][0]["base64"]) == jpeg
    assert by_path["/b"]["attachments"] == []
    assert by_path["/b"]["title"] == render(event, "en")[0]
