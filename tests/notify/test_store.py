"""The notification store on real SQLite and real PostgreSQL: the migration, channels
(secrets kept back), events recorded with their deliveries in one go, the outbox's order
per (channel, printer), claims that two outboxes never share, and the settings row."""

from __future__ import annotations

import asyncio
from datetime import UTC, datetime, timedelta

import pytest
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import func, select, text, update
from sqlalchemy.engine import Connection
from sqlalchemy.ext.asyncio import AsyncEngine, create_async_engine

from kybercore.api.errors import error_status
from kybercore.db import open_database
from kybercore.db.engine import parse_database_url
from kybercore.db.migrate import alembic_config, head_revision
from kybercore.errors import ChannelNotFound, FileNotFound
from kybercore.notify.models import NoiseSettings
from kybercore.notify.rules import ChannelRules
from kybercore.notify.store import NotifyStore
from kybercore.notify.tables import metadata, notify_events
from kybercore.notify.texts import render
from tests.notify.conftest import SECRET, add_webhook, fleet_event

LATER = timedelta(hours=1)


def _drift(conn: Connection) -> list[object]:
    # The notification tables only: the other parts' tables have tests of their own.
    def notify_only(name: str | None, kind: str, _parent: object) -> bool:
        return kind != "table" or name in metadata.tables

    context = MigrationContext.configure(conn, opts={"include_name": notify_only})
    return list(compare_metadata(context, metadata))


async def test_the_migrated_database_has_the_tables_the_code_uses(database: AsyncEngine) -> None:
    async with database.connect() as conn:
        assert await conn.run_sync(_drift) == []


async def test_a_database_at_0003_is_upgraded_to_head_with_its_data(database_url: str) -> None:
    # A KyberCore of before notifications: migrated to 0003 only, with an audit row.
    engine = create_async_engine(parse_database_url(database_url))

    def to_0003(conn: Connection) -> None:
        config = alembic_config()
        config.attributes["connection"] = conn
        command.upgrade(config, "0003_audit")

    async with engine.begin() as conn:
        await conn.run_sync(to_0003)
        await conn.execute(
            text(
                "INSERT INTO audit (at, actor, role, action, target, params, outcome, client, "
                "request_id) VALUES (CURRENT_TIMESTAMP, 'ana', 'admin', 'printer.edit', "
                "'printer:a', '{}', 'ok', '', '')"
            )
        )
    await engine.dispose()
    engine = await open_database(database_url)
    try:
        async with engine.connect() as conn:
            assert await conn.scalar(text("SELECT version_num FROM alembic_version")) == (
                head_revision()
            )
            assert await conn.scalar(text("SELECT count(*) FROM audit")) == 1
            assert await conn.run_sync(_drift) == []
        store = NotifyStore(engine)
        channel = await add_webhook(store, "http://127.0.0.1:9/hook")
        assert [c.id for c in await store.channels()] == [channel.id]
    finally:
        await engine.dispose()


async def test_channels_keep_their_secret_back_and_mask_their_target(
    store: NotifyStore,
) -> None:
    hook = await add_webhook(store, "https://bob:pw@hooks.example/in/abc?token=t0k#x", name="ops")
    tele = await store.add_channel(
        name="phone", kind="apprise", target="tgram://123456:ABCDEFsecret/987654",
        secret=None, rules=ChannelRules(language="es"), enabled=False, user="eva",
    )  # fmt: skip
    assert [c.id for c in await store.channels()] == [hook.id, tele.id]
    assert hook.has_secret
    assert not tele.has_secret
    assert await store.secret(hook.id) == SECRET
    assert await store.secret(tele.id) is None
    shown = hook.public()
    assert shown["target"] == "https://hooks.example/in/abc"
    assert tele.public()["target"] == "tgram://…7654"
    for public in (shown, tele.public()):
        text_of = repr(public)
        for secret in (SECRET, "pw", "t0k", "ABCDEFsecret"):
            assert secret not in text_of
    assert shown["created_by"] == "ana"
    assert shown["rules"] == ChannelRules().to_json()
    assert (await store.channel(tele.id)).rules.language == "es"


async def test_a_channel_changes_only_what_is_given_and_a_secret_can_be_removed(
    store: NotifyStore,
) -> None:
    hook = await add_webhook(store, "http://127.0.0.1:9/a")
    changed = await store.update_channel(
        hook.id, user="eva", name="renamed", rules=ChannelRules(language="es"), enabled=False
    )
    assert (changed.name, changed.rules.language, changed.enabled) == ("renamed", "es", False)
    assert changed.target == hook.target
    assert changed.has_secret
    assert changed.created_by == "ana"
    assert changed.updated_by == "eva"
    cleared = await store.update_channel(hook.id, user="eva", secret=None)
    assert not cleared.has_secret
    assert await store.secret(hook.id) is None
    with pytest.raises(TypeError, match="kind"):
        await store.update_channel(hook.id, user="eva", kind="apprise")


async def test_an_unknown_channel_is_channel_not_found_which_is_a_404(
    store: NotifyStore,
) -> None:
    for call in (
        store.channel(42),
        store.secret(42),
        store.update_channel(42, user="ana", name="x"),
        store.remove_channel(42),
    ):
        with pytest.raises(ChannelNotFound, match="No notification channel with id 42") as err:
            await call
    assert error_status(err.value) == (404, "channel_not_found")
    with pytest.raises(FileNotFound):
        await store.delivery(42)


async def test_record_writes_one_delivery_per_routed_channel_and_returns_the_pending(
    store: NotifyStore, database: AsyncEngine
) -> None:
    sent, quiet, skipped = [
        await add_webhook(store, f"http://127.0.0.1:9/{n}", name=n) for n in ("s", "q", "k")
    ]
    event = fleet_event("print_failed", "a")
    routes = {sent.id: "deliver", quiet.id: "quiet_hours", skipped.id: "skip", 999: "deliver"}
    pending = await store.record(event, b"\xff\xd8\xffjpeg", routes)
    log = await store.deliveries()
    assert [(d.channel_name, d.status) for d in log] == [("q", "quiet_hours"), ("s", "pending")]
    assert pending == [log[1].id]
    assert log[1].to_json()["kind"] == "print_failed"
    assert log[1].printer_id == "a"
    assert log[1].title == render(event, "en")[0]
    # Recorded again (a retry of the caller): nothing new.
    assert await store.record(event, None, {sent.id: "deliver"}) == []
    assert len(await store.deliveries()) == 2
    # Nothing to deliver: the event is not kept at all.
    lonely = fleet_event("print_started", "a")
    assert await store.record(lonely, None, {skipped.id: "skip"}) == []
    async with database.connect() as conn:
        assert await conn.scalar(select(func.count()).select_from(notify_events)) == 1


async def test_a_delivery_is_titled_in_its_channels_language(store: NotifyStore) -> None:
    en = await add_webhook(store, "http://127.0.0.1:9/en", name="en")
    es = await add_webhook(store, "http://127.0.0.1:9/es", name="es", language="es")
    event = fleet_event("printer_offline", "a", was="printing")
    await store.record(event, None, {en.id: "deliver", es.id: "deliver"})
    by_channel = {d.channel_name: d.title for d in await store.deliveries()}
    assert by_channel == {"en": render(event, "en")[0], "es": render(event, "es")[0]}
    assert by_channel["en"] != by_channel["es"]
    only_es = await store.deliveries(channel_id=es.id, limit=5)
    assert [d.channel_id for d in only_es] == [es.id]


async def test_due_hands_out_each_printers_oldest_pending_delivery_only(
    store: NotifyStore,
) -> None:
    hook = await add_webhook(store, "http://127.0.0.1:9/h")
    other = await add_webhook(store, "http://127.0.0.1:9/o", name="other")
    a1, a2, b1, fleet = [
        (await store.record(fleet_event(printer=p), None, {hook.id: "deliver"}))[0]
        for p in ("a", "a", "b", None)
    ]
    (o1,) = await store.record(fleet_event(printer="a"), None, {other.id: "deliver"})
    now = datetime.now(UTC)
    due = await store.due(now)
    assert [x.id for x in due] == [a1, b1, fleet, o1]
    assert due[0].event.printer is not None
    assert due[0].event.printer.id == "a"
    assert (due[0].target, due[0].secret, due[0].attempts) == (hook.target, SECRET, 0)
    # Claimed: not handed out again, even to another outbox, while the claim lasts.
    assert await store.due(now) == []
    assert await store.next_due() == now + timedelta(seconds=120)
    # a1 fails and waits: a2 stays behind it; the others are delivered.
    await store.mark_retry(a1, "The receiver answered HTTP 500", 500, now + LATER)
    for delivered in (b1, fleet, o1):
        await store.mark_delivered(delivered, 200)
    assert await store.due(now + timedelta(minutes=5)) == []
    assert [x.id for x in await store.due(now + LATER)] == [a1]
    # Given up: a1 no longer holds a2 back.
    await store.mark_failed(a1, "The receiver answered HTTP 500", 500)
    assert [x.id for x in await store.due(now + LATER)] == [a2]
    failed = await store.delivery(a1)
    assert (failed.status, failed.attempts, failed.response_code) == ("failed", 2, 500)
    assert failed.last_error == "The receiver answered HTTP 500"
    assert failed.next_at is None


async def test_a_claim_released_is_due_at_once_and_a_delivered_one_keeps_its_last_error(
    store: NotifyStore,
) -> None:
    hook = await add_webhook(store, "http://127.0.0.1:9/h")
    (one,) = await store.record(fleet_event(), None, {hook.id: "deliver"})
    await store.due(datetime.now(UTC))
    await store.release([one])
    assert [x.id for x in await store.due(datetime.now(UTC))] == [one]
    await store.mark_retry(one, "Could not reach the receiver", None, datetime.now(UTC))
    await store.mark_delivered(one, 204)
    done = await store.delivery(one)
    assert (done.status, done.attempts, done.response_code) == ("delivered", 2, 204)
    assert done.last_error == "Could not reach the receiver"
    assert done.delivered_at is not None
    assert done.next_at is None
    assert await store.next_due() is None
    await store.mark_failed(one, "late", None)  # settled already: nothing changes
    assert (await store.delivery(one)).status == "delivered"


async def test_two_outboxes_on_one_database_never_claim_the_same_delivery(
    database_url: str,
) -> None:
    engines = [await open_database(database_url) for _ in range(2)]
    try:
        first, second = (NotifyStore(engine) for engine in engines)
        hook = await add_webhook(first, "http://127.0.0.1:9/h")
        for printer in "abcdefgh":
            await first.record(fleet_event(printer=printer), None, {hook.id: "deliver"})
        now = datetime.now(UTC)
        claims = await asyncio.gather(*(s.due(now) for s in (first, second, first, second)))
        ids = [d.id for claim in claims for d in claim]
        assert len(ids) == len(set(ids)) == 8
    finally:
        for engine in engines:
            await engine.dispose()


async def test_the_snapshot_is_kept_until_no_delivery_can_send_it(store: NotifyStore) -> None:
    one, two = [await add_webhook(store, f"http://127.0.0.1:9/{n}", name=n) for n in "12"]
    event = fleet_event()
    first, second = await store.record(event, b"JPEG", {one.id: "deliver", two.id: "deliver"})
    assert [d.has_snapshot for d in await store.due(datetime.now(UTC))] == [True, True]
    await store.mark_delivered(first, 200)
    assert await store.snapshot(event.id) == b"JPEG"
    await store.mark_failed(second, "gone", 410)
    assert await store.snapshot(event.id) is None
    # Only quiet hours: nothing will be sent, so no snapshot is stored.
    quiet = fleet_event()
    await store.record(quiet, b"JPEG", {one.id: "quiet_hours"})
    assert await store.snapshot(quiet.id) is None


async def test_removing_a_channel_removes_its_deliveries_not_the_events(
    store: NotifyStore, database: AsyncEngine
) -> None:
    keep, drop = [await add_webhook(store, f"http://127.0.0.1:9/{n}", name=n) for n in "kd"]
    event = fleet_event()
    await store.record(event, None, {keep.id: "deliver", drop.id: "deliver"})
    await store.remove_channel(drop.id)
    assert [d.channel_id for d in await store.deliveries()] == [keep.id]
    assert [c.id for c in await store.channels()] == [keep.id]
    async with database.connect() as conn:
        assert await conn.scalar(select(func.count()).select_from(notify_events)) == 1


async def test_settings_are_the_defaults_until_saved_then_what_was_saved(
    store: NotifyStore,
) -> None:
    assert await store.settings() == NoiseSettings()
    tuned = NoiseSettings(cooldown_s=60.0, storm_threshold=5, offline_grace_s=900.0)
    await store.save_settings(tuned)
    assert await store.settings() == tuned
    again = NoiseSettings(plate_wait_s=60.0)
    await store.save_settings(again)
    assert await store.settings() == again


async def test_an_event_this_kybercore_cannot_read_is_failed_not_left_blocking(
    store: NotifyStore, database: AsyncEngine
) -> None:
    hook = await add_webhook(store, "http://127.0.0.1:9/h")
    odd, fine = fleet_event(printer="a"), fleet_event(printer="a")
    (first,) = await store.record(odd, None, {hook.id: "deliver"})
    (second,) = await store.record(fine, None, {hook.id: "deliver"})
    # As a newer KyberCore with an event kind this one does not know would write it.
    future = {**odd.to_json(), "type": "spaghetti_detected"}
    async with database.begin() as conn:
        await conn.execute(
            update(notify_events).where(notify_events.c.id == odd.id).values(payload=future)
        )
    assert await store.due(datetime.now(UTC)) == []
    assert [x.id for x in await store.due(datetime.now(UTC))] == [second]
    failed = await store.delivery(first)
    assert failed.status == "failed"
    assert failed.last_error.startswith("KyberCore cannot read this event")
    # The log still lists it, under its kind.
    assert [d.title for d in await store.deliveries()][1] == "print_failed"
