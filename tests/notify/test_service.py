"""The notification service without live printers: a fleet whose printers are unreachable,
the queue's real store on SQLite, and a real webhook receiver on loopback.

Tests, settings and the queue's own findings (plates waiting, jobs blocked) need no
printer; what the printers' transitions send is tested in test_live.py.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from dataclasses import replace
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import httpx
import pytest
from sqlalchemy import event, text
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.db import default_database_url, open_database
from kybercore.jobs.store import JobStore
from kybercore.moonraker.events import SessionEvent, StatusDelta
from kybercore.notify.models import NoiseSettings
from kybercore.notify.outbox import STORE_CALLS_AT_ONCE
from kybercore.notify.printers import FleetNotifyPrinters
from kybercore.notify.rules import QuietHours
from kybercore.notify.senders import SIGNATURE_HEADER, TIMESTAMP_HEADER, verify
from kybercore.notify.service import READS_AT_ONCE
from kybercore.registry.models import PrinterConfig
from kybercore.sim.stack import free_port
from tests.helpers import wait_for
from tests.jobs.conftest import new_job
from tests.notify.conftest import fleet_event
from tests.notify.live_notify import FAST, SECRET, add_webhook, kinds, received, running_notify
from tests.notify.receiver import Receiver

README = Path(__file__).parents[2] / "README.md"
DELIVERED_WITHIN = 10.0
"""A delivery to a loopback receiver takes milliseconds; a retry 0.2 s: 10 s of slack."""


def readme_verify() -> Callable[..., bool]:
    """The signature check the README gives webhook receivers (its Python block after
    "### The webhook"), compiled from the README itself."""
    text = README.read_text()
    code = text[text.index("### The webhook") :].split("```python\n", 1)[1].split("```", 1)[0]
    namespace: dict[str, Any] = {}
    exec(compile(code, str(README), "exec"), namespace)  # our own README's snippet
    verify: Callable[..., bool] = namespace["verify"]
    return verify


def unreachable(*ids: str, location: str = "Lab") -> list[PrinterConfig]:
    """Printers whose Moonraker is not there (a port nobody listens on)."""
    return [
        PrinterConfig(
            id=pid, name=f"Printer {pid}", location=location,
            moonraker_url=f"http://127.0.0.1:{free_port()}",
        )
        for pid in ids
    ]  # fmt: skip


@pytest.fixture
async def engine(tmp_path: Path) -> AsyncIterator[AsyncEngine]:
    database = await open_database(default_database_url(tmp_path))
    yield database
    await database.dispose()


async def test_a_test_message_is_signed_and_answered_with_its_outcome(
    tmp_path: Path, http: httpx.AsyncClient, engine: AsyncEngine, receiver: Receiver
) -> None:
    async with running_notify([], tmp_path, http, engine) as notify:
        channel = await add_webhook(notify, receiver)
        delivery = await notify.send_test(channel.id, "alice")
        assert (delivery.status, delivery.response_code, delivery.attempts) == ("delivered", 200, 1)
        [request] = receiver.accepted
        assert verify(
            SECRET, request.headers[TIMESTAMP_HEADER.lower()], request.body,
            request.headers[SIGNATURE_HEADER.lower()],
        )  # fmt: skip
        # The README's snippet agrees, and refuses a body changed in transit or a stale one.
        readme = readme_verify()
        assert readme(SECRET, request.headers, request.body)
        assert not readme(SECRET, request.headers, request.body + b" ")
        assert not readme("another-secret-of-the-same-length-0123", request.headers, request.body)
        assert not readme(SECRET, request.headers, request.body, max_age=-1)
        body = request.json()
        assert (body["type"], body["id"], body["printer"]) == ("test", delivery.event_id, None)
        assert body["title"]
        assert [d.id for d in await notify.store.deliveries(channel.id)] == [delivery.id]


async def test_a_test_to_a_receiver_that_is_down_answers_pending_with_the_error(
    tmp_path: Path, http: httpx.AsyncClient, engine: AsyncEngine
) -> None:
    down = Receiver()  # never started: connections are refused
    async with running_notify([], tmp_path, http, engine) as notify:
        channel = await add_webhook(notify, down)
        delivery = await notify.send_test(channel.id, "alice", wait=DELIVERED_WITHIN)
        assert (delivery.status, delivery.attempts) == ("pending", 1)
        assert "Could not reach" in delivery.last_error
        assert delivery.next_at is not None


async def test_settings_apply_at_once_and_outlive_a_restart(
    tmp_path: Path, http: httpx.AsyncClient, engine: AsyncEngine
) -> None:
    tuned = NoiseSettings(cooldown_s=42.0, fold_window_s=3.0, storm_threshold=7)
    async with running_notify([], tmp_path, http, engine) as notify:
        await notify.apply_settings(tuned)
        assert notify.settings == tuned
    async with running_notify([], tmp_path, http, engine, settings=tuned) as again:
        assert again.settings == tuned
        assert await again.store.settings() == tuned


async def test_a_plate_left_waiting_is_told_once_with_its_job(
    tmp_path: Path, http: httpx.AsyncClient, engine: AsyncEngine, receiver: Receiver
) -> None:
    printers = unreachable("p1")
    # The job is queued for a moment before it is reserved, on a printer that cannot take
    # it: told "blocked" at once (job_blocked_s=0), that would be a second message.
    settings = replace(FAST, job_blocked_s=3600.0)
    async with running_notify(printers, tmp_path, http, engine, settings) as notify:
        await add_webhook(notify, receiver)
        store = notify.queue.store
        job = await store.create_job(new_job(name="bracket.gcode"), "alice")
        attempt = await store.reserve(job.id, "p1")
        assert attempt is not None
        await store.finish(attempt.id, "completed")

        await wait_for(lambda: received(receiver, kind="plate_waiting"), DELIVERED_WITHIN,
                       "the plate_waiting message")  # fmt: skip
        rounds = notify.checks.rounds
        await wait_for(lambda: notify.checks.rounds >= rounds + 3, DELIVERED_WITHIN, "3 rounds")
        [told] = received(receiver, kind="plate_waiting")
        assert told["printer"]["id"] == "p1"
        assert (told["data"]["job_id"], told["data"]["job_name"]) == (job.id, "bracket.gcode")
        assert kinds(receiver) == ["plate_waiting"]


async def test_a_job_no_printer_can_take_is_told_blocked_with_the_reasons_once(
    tmp_path: Path, http: httpx.AsyncClient, engine: AsyncEngine, receiver: Receiver
) -> None:
    now = datetime.now()
    quiet = QuietHours(
        (now - timedelta(hours=1)).strftime("%H:%M"), (now + timedelta(hours=1)).strftime("%H:%M")
    )
    async with running_notify(unreachable("p1", "p2"), tmp_path, http, engine) as notify:
        await add_webhook(notify, receiver)
        asleep = await add_webhook(notify, receiver, "/asleep", quiet_hours=quiet)
        job = await notify.queue.store.create_job(new_job(quantity=2), "alice")

        await wait_for(lambda: received(receiver, kind="job_blocked"), DELIVERED_WITHIN,
                       "the job_blocked message")  # fmt: skip
        rounds = notify.checks.rounds
        await wait_for(lambda: notify.checks.rounds >= rounds + 3, DELIVERED_WITHIN, "3 rounds")
        [told] = received(receiver, kind="job_blocked")
        assert (told["printer"], told["data"]["job_id"], told["data"]["left"]) == (None, job.id, 2)
        assert "p1: " in told["data"]["reason"]
        assert "p2: " in told["data"]["reason"]
        # A warning in quiet hours is recorded for that channel, never sent.
        [held] = await notify.store.deliveries(asleep.id)
        assert (held.kind, held.status) == ("job_blocked", "quiet_hours")
        assert received(receiver, "/asleep") == []


async def test_a_job_the_queue_blocks_after_its_failures_is_told_at_once(
    tmp_path: Path, http: httpx.AsyncClient, engine: AsyncEngine, receiver: Receiver
) -> None:
    slow = replace(FAST, plate_wait_s=3600.0, job_blocked_s=3600.0)
    async with running_notify(unreachable("p1"), tmp_path, http, engine, slow) as notify:
        await add_webhook(notify, receiver)
        store: JobStore = notify.queue.store
        job = await store.create_job(new_job(max_attempts=1), "alice")
        rounds = notify.checks.rounds
        await wait_for(lambda: notify.checks.rounds > rounds, DELIVERED_WITHIN, "a first round")
        attempt = await store.reserve(job.id, "p1")
        assert attempt is not None
        await store.finish(attempt.id, "failed", reason="Heater extruder not heating")

        await wait_for(lambda: received(receiver, kind="job_blocked"), DELIVERED_WITHIN,
                       "the job_blocked message")  # fmt: skip
        [told] = received(receiver, kind="job_blocked")
        assert told["data"]["state"] == "blocked"
        assert "not heating" in told["data"]["reason"]


async def test_the_listener_skips_updates_nothing_reads_and_never_raises(
    tmp_path: Path, http: httpx.AsyncClient, engine: AsyncEngine, monkeypatch: pytest.MonkeyPatch
) -> None:
    async with running_notify(unreachable("p1"), tmp_path, http, engine) as notify:
        fleet = notify.queue.fleet
        listeners: list[Callable[[str, SessionEvent], None]] = []

        def listen(listener: Callable[[str, SessionEvent], None], _interest: Any) -> Any:
            listeners.append(listener)
            return lambda: None

        monkeypatch.setattr(fleet, "listen", listen)
        heard: list[str] = []
        FleetNotifyPrinters(fleet, http).listen(heard.append)
        [hear] = listeners
        hear("p1", StatusDelta({"extruder": {"temperature": 200.0}}, 1.0))
        assert heard == []
        hear("p1", StatusDelta({"print_stats": {"state": "printing"}}, 1.0))
        hear("p1", StatusDelta({"filament_switch_sensor runout": {"enabled": False}}, 1.0))
        assert heard == ["p1", "p1"]
        # A printer the fleet no longer has: logged, not raised into the fleet.
        notify._on_change("gone")


async def test_stopping_records_the_events_still_held_for_folding(
    tmp_path: Path, http: httpx.AsyncClient, engine: AsyncEngine
) -> None:
    # Not told "blocked" in the moment the job waits for its reservation (as above).
    held = replace(FAST, fold_window_s=3600.0, job_blocked_s=3600.0)
    async with running_notify(unreachable("p1"), tmp_path, http, engine, held) as notify:
        channel = await add_webhook(notify, Receiver())  # down: what is recorded stays
        store = notify.queue.store
        attempt = await store.reserve((await store.create_job(new_job(), "alice")).id, "p1")
        assert attempt is not None
        await store.finish(attempt.id, "completed")
        rounds = notify.checks.rounds
        await wait_for(lambda: notify.checks.rounds >= rounds + 2, DELIVERED_WITHIN, "2 rounds")
        assert await notify.store.deliveries(channel.id) == []  # held for an hour
    # The window had an hour to go: the stop recorded it for the next start to send.
    [recorded] = await notify.store.deliveries(channel.id)
    assert (recorded.kind, recorded.status) == ("plate_waiting", "pending")


async def test_a_database_failure_is_logged_and_the_service_goes_on(
    tmp_path: Path,
    http: httpx.AsyncClient,
    engine: AsyncEngine,
    caplog: pytest.LogCaptureFixture,
) -> None:
    async with running_notify(unreachable("p1", "p2"), tmp_path, http, engine) as notify:
        async with engine.begin() as conn:  # the channels' table gone: every event fails
            await conn.execute(text("DROP TABLE notify_channels"))
        store = notify.queue.store
        attempt = await store.reserve((await store.create_job(new_job(), "al")).id, "p1")
        assert attempt is not None
        await store.finish(attempt.id, "completed")
        await store.create_job(new_job(), "al")

        def failures() -> int:
            return sum("could not be recorded" in r.getMessage() for r in caplog.records)

        # Two events (the plate waiting, the job blocked), each failing on its own.
        await wait_for(lambda: failures() >= 2, DELIVERED_WITHIN, "both failures logged")
        ticks = notify.ticks
        await wait_for(lambda: notify.ticks > ticks + 2, DELIVERED_WITHIN, "the ticks go on")


async def test_a_burst_of_events_is_recorded_whole_without_taking_every_connection(
    tmp_path: Path, http: httpx.AsyncClient, engine: AsyncEngine
) -> None:
    # A bulk pause of a whole farm emits an event per printer at once. Each event once read
    # the channels on a connection of its own: the pool ran dry, its timeout lost events,
    # and the fleet's own writes waited behind them.
    burst = 60  # four times the pool (5 + 10 overflow)
    out, peak = 0, 0

    def checked_out(*_: Any) -> None:
        nonlocal out, peak
        out += 1
        peak = max(peak, out)

    def checked_in(*_: Any) -> None:
        nonlocal out
        out -= 1

    async with running_notify([], tmp_path, http, engine) as notify:
        channel = await add_webhook(notify, Receiver())  # down: deliveries stay pending
        pool = engine.sync_engine.pool
        event.listen(pool, "checkout", checked_out)
        event.listen(pool, "checkin", checked_in)
        try:
            for index in range(burst):
                notify._emit(fleet_event(printer=f"p{index}"))

            async def all_recorded() -> bool:
                return len(await notify.store.deliveries(channel.id, limit=burst)) == burst

            await wait_for(all_recorded, DELIVERED_WITHIN * 3, f"{burst} events recorded")
        finally:
            event.remove(pool, "checkout", checked_out)
            event.remove(pool, "checkin", checked_in)
    # The reads, the recorder, the queue watcher, the outbox's loop and its sends, and this
    # test's polling: never the pool's 15.
    assert peak <= READS_AT_ONCE + 1 + 1 + 1 + STORE_CALLS_AT_ONCE + 1, peak
