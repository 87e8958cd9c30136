"""Notifications over real Moonraker + Klippy printers and a real loopback webhook receiver:
a printer lost while printing is told once (and its recovery once), an idle one switched
off is not news, a finished print and an emergency stop are told, and what a receiver
missed while KyberCore restarted reaches it afterwards, once."""

from __future__ import annotations

import asyncio
import base64
import io
import math
from collections.abc import AsyncIterator, Callable
from dataclasses import replace
from pathlib import Path

import httpx
import pytest
from PIL import Image
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.api.app import create_app
from kybercore.db import default_database_url, open_database
from kybercore.moonraker.client import MoonrakerClient
from kybercore.notify.service import NotifyService
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import PrinterRegistry, write_printers
from kybercore.sim.stack import PrinterStack
from tests.helpers import travel_gcode, wait_for
from tests.notify.live_notify import (
    FAST,
    RETRY,
    SECRET,
    add_webhook,
    kinds,
    received,
    running_notify,
)
from tests.notify.receiver import Receiver

pytestmark = pytest.mark.integration

SHORT = travel_gcode(moves=4, feedrate=6000)
"""Homing plus 2 s of moves."""
LONG = travel_gcode(moves=300, feedrate=1200)
"""12 minutes: still printing when its printer comes back."""
READY_WITHIN = 60.0
"""A printer connects in a second or two and a Moonraker restart takes a few: 60 s."""
TOLD_WITHIN = 30.0
"""An event reaches the receiver a fold window (0.3 s) plus milliseconds after KyberCore
sees it, which is within a second of it happening: 30 s of slack on a busy machine."""
PRINT_WITHIN = 120.0


@pytest.fixture
async def engine(tmp_path: Path) -> AsyncIterator[AsyncEngine]:
    database = await open_database(default_database_url(tmp_path))
    yield database
    await database.dispose()


def config(stack: PrinterStack, location: str = "Room B") -> PrinterConfig:
    name = stack.options.name
    return PrinterConfig(
        id=name, name=f"Printer {name}", location=location, moonraker_url=stack.url
    )


def client_of(notify: NotifyService, stack: PrinterStack) -> MoonrakerClient:
    client = notify.queue.fleet.sessions.get(stack.options.name).client
    assert client is not None
    return client


async def ready(notify: NotifyService, *stacks: PrinterStack) -> None:
    """Wait until every printer is online with Klippy ready, as KyberCore sees it."""

    def all_ready() -> bool:
        views = [notify.queue.fleet.view(stack.options.name) for stack in stacks]
        return all(v["connection"] == "online" and v["klippy_state"] == "ready" for v in views)

    await wait_for(all_ready, READY_WITHIN, "the printers online and ready")


async def settled(notify: NotifyService) -> None:
    """Wait until a fold window and two ticks more have passed and nothing recorded is
    still waiting to be sent: whatever the events so far would send is sent."""
    ticks = notify.ticks + math.ceil(notify.settings.fold_window_s / 0.05) + 2
    await wait_for(lambda: notify.ticks >= ticks, TOLD_WITHIN, "a fold window and two ticks")

    async def sent() -> bool:
        return all(d.status != "pending" for d in await notify.store.deliveries())

    await wait_for(sent, TOLD_WITHIN, "every delivery sent")


def offline(notify: NotifyService, stack: PrinterStack) -> bool:
    return bool(notify.queue.fleet.view(stack.options.name)["connection"] != "online")


async def test_a_printer_lost_while_printing_is_told_once_and_an_idle_one_not_at_all(
    own_printer: PrinterStack,
    start_stack: Callable[..., PrinterStack],
    tmp_path: Path,
    http: httpx.AsyncClient,
    engine: AsyncEngine,
    receiver: Receiver,
) -> None:
    busy, idle = own_printer, start_stack("notify-idle")
    try:
        async with running_notify([config(busy), config(idle)], tmp_path, http, engine) as notify:
            await add_webhook(notify, receiver)
            await ready(notify, busy, idle)
            client = client_of(notify, busy)
            await client.upload("notify-long.gcode", LONG)
            await client.print_start("notify-long.gcode")
            await wait_for(lambda: kinds(receiver) == ["print_started"], TOLD_WITHIN, "started")

            for stack in (busy, idle):
                await asyncio.to_thread(stack.stop_moonraker)
            await wait_for(lambda: offline(notify, busy) and offline(notify, idle), TOLD_WITHIN,
                           "both printers offline")  # fmt: skip
            await settled(notify)
            [lost] = received(receiver, kind="printer_offline")
            assert (lost["printer"]["id"], lost["data"]["was"]) == (busy.options.name, "printing")
            assert lost["severity"] == "critical"

            for stack in (busy, idle):
                await asyncio.to_thread(stack.start_moonraker)
            await ready(notify, busy, idle)
            await settled(notify)
            [back] = received(receiver, kind="printer_recovered")
            assert back["printer"]["id"] == busy.options.name
            # The print went on while Moonraker was away: nothing else is news.
            assert kinds(receiver) == ["print_started", "printer_offline", "printer_recovered"]
            await client_of(notify, busy).print_cancel()
    finally:
        idle.stop()


@pytest.mark.timeout(300)
async def test_a_room_of_twelve_lost_together_is_one_message_and_a_flap_is_not_told_again(
    own_printer: PrinterStack,
    tmp_path: Path,
    http: httpx.AsyncClient,
    engine: AsyncEngine,
    receiver: Receiver,
) -> None:
    # Twelve printers of Room B behind one Moonraker: stopping it is the room losing power.
    room = [
        PrinterConfig(
            id=f"b{n:02}", name=f"B{n:02}", location="Room B", moonraker_url=own_printer.url
        )
        for n in range(1, 13)
    ]
    alerts = frozenset({"printer_offline", "storm_offline", "printer_recovered"})
    # The room's sessions reconnect within ~1.5 s of Moonraker's return (refused connections
    # are retried every 1-1.5 s): a window of 8 s folds their recoveries with 5x slack.
    settings = replace(FAST, cooldown_s=3600.0, fold_window_s=8.0, storm_threshold=3)
    async with running_notify(room, tmp_path, http, engine, settings) as notify:
        await add_webhook(notify, receiver, events=alerts)
        await wait_for(
            lambda: all(notify.queue.fleet.view(p.id)["klippy_state"] == "ready" for p in room),
            READY_WITHIN,
            "the room online",
        )
        client = notify.queue.fleet.sessions.get("b01").client
        assert client is not None
        await client.upload("notify-long.gcode", LONG)
        await client.print_start("notify-long.gcode")

        def printing() -> bool:
            live = [notify.queue.fleet.sessions.get(p.id).live for p in room]
            return all(x.status.get("print_stats", {}).get("state") == "printing" for x in live)

        await wait_for(printing, READY_WITHIN, "the room printing")
        for flap in range(2):
            await asyncio.to_thread(own_printer.stop_moonraker)
            await wait_for(
                lambda: all(notify.queue.fleet.view(p.id)["connection"] != "online" for p in room),
                TOLD_WITHIN,
                "the room offline",
            )
            await settled(notify)
            # One message for the room; the second loss, within the cooldown, none.
            told = ["storm_offline"] if flap == 0 else ["storm_offline", "printer_recovered"]
            assert kinds(receiver) == told
            await asyncio.to_thread(own_printer.start_moonraker)
            await wait_for(
                lambda: all(notify.queue.fleet.view(p.id)["klippy_state"] == "ready" for p in room),
                READY_WITHIN,
                "the room back",
            )
            await settled(notify)
            assert kinds(receiver) == ["storm_offline", "printer_recovered"]
        storm, back = received(receiver)
        assert (storm["printer"], storm["data"]["location"]) == (None, "Room B")
        assert sorted(storm["data"]["printers"]) == [p.id for p in room]
        assert storm["title"] == "Room B: 12 printers offline"
        assert (back["printer"], back["data"]["count"]) == (None, 12)
        await client.print_cancel()


async def test_a_finished_print_is_told_started_and_completed_with_the_webcams_picture(
    own_printer: PrinterStack, tmp_path: Path, receiver: Receiver
) -> None:
    # The virtual printer's own webcam (sim/webcam.py), as Moonraker lists it.
    path = tmp_path / "printers.json"
    write_printers(path, [config(own_printer)])
    options = {"tick": 0.05, "queue_poll": 0.1, "outbox_options": RETRY}
    app = create_app(PrinterRegistry(path), notify_options=options)
    async with (
        app.router.lifespan_context(app),
        httpx.AsyncClient(
            transport=httpx.ASGITransport(app), base_url="http://127.0.0.1", timeout=30
        ) as api,
    ):
        settings = {**(await api.get("/api/notifications/settings")).json(), "cooldown_s": 0}
        assert (await api.put("/api/notifications/settings", json=settings)).status_code == 200
        channel = {"name": "hook", "kind": "webhook", "target": receiver.url(), "secret": SECRET}
        assert (await api.post("/api/notifications/channels", json=channel)).status_code == 201
        notify: NotifyService = app.state.notify
        await ready(notify, own_printer)
        client = client_of(notify, own_printer)
        await client.upload("notify-short.gcode", SHORT)
        await client.print_start("notify-short.gcode")
        await wait_for(lambda: "print_completed" in kinds(receiver), PRINT_WITHIN, "completed")

        async def logged() -> list[tuple[str, str]]:
            log = (await api.get("/api/notifications/deliveries")).json()
            return [(d["kind"], d["status"]) for d in log]

        # The receiver has it before the outbox has written down the receiver's answer.
        async def all_delivered() -> bool:
            return all(status == "delivered" for _, status in await logged())

        await wait_for(all_delivered, TOLD_WITHIN, "every delivery recorded")
        # Recorded in the order they happened (newest first)...
        assert await logged() == [
            ("print_completed", "delivered"),
            ("print_started", "delivered"),
        ]
        # ...and sent side by side, so they may arrive in either order (once, in a full
        # run, only the completed one had arrived when the receiver was first read).
        assert sorted(kinds(receiver)) == ["print_completed", "print_started"]
        for told in received(receiver):
            assert told["data"]["filename"] == "notify-short.gcode"
            assert told["snapshot"]["filename"] == f"{own_printer.options.name}.jpg"
            with Image.open(io.BytesIO(base64.b64decode(told["snapshot"]["base64"]))) as shot:
                assert (shot.format, shot.size) == ("JPEG", (640, 480))


async def test_an_emergency_stop_is_told_as_a_klippy_shutdown_and_its_recovery(
    own_printer: PrinterStack,
    tmp_path: Path,
    http: httpx.AsyncClient,
    engine: AsyncEngine,
    receiver: Receiver,
) -> None:
    async with running_notify([config(own_printer)], tmp_path, http, engine) as notify:
        await add_webhook(notify, receiver)
        await ready(notify, own_printer)
        pid = own_printer.options.name
        await notify.queue.fleet.act(pid, "emergency_stop")
        await wait_for(lambda: kinds(receiver) == ["klippy_shutdown"], TOLD_WITHIN, "shutdown")
        [told] = received(receiver)
        assert (told["printer"]["id"], told["severity"]) == (pid, "critical")

        await notify.queue.fleet.act(pid, "firmware_restart")
        await ready(notify, own_printer)
        await wait_for(lambda: "printer_recovered" in kinds(receiver), TOLD_WITHIN, "recovered")
        await settled(notify)
        assert kinds(receiver) == ["klippy_shutdown", "printer_recovered"]
        assert received(receiver, kind="printer_recovered")[0]["data"]["what"] == "klippy"


async def test_what_a_receiver_missed_across_a_restart_of_kybercore_arrives_once_in_order(
    printer: PrinterStack, tmp_path: Path, http: httpx.AsyncClient, engine: AsyncEngine
) -> None:
    receiver = Receiver()  # down until KyberCore has stopped
    printers = [config(printer)]
    async with running_notify(printers, tmp_path, http, engine) as notify:
        channel = await add_webhook(notify, receiver)
        await ready(notify, printer)
        client = client_of(notify, printer)
        await client.upload("notify-short.gcode", SHORT)
        await client.print_start("notify-short.gcode")

        async def both_recorded() -> bool:
            # In order per printer: the second waits behind the first, which fails.
            log = {d.kind: d for d in await notify.store.deliveries(channel.id)}
            return set(log) == {"print_started", "print_completed"} and (
                log["print_started"].attempts > 0
            )

        await wait_for(both_recorded, PRINT_WITHIN, "both events recorded, the first tried")
    pending = await notify.store.deliveries(channel.id)
    assert {d.status for d in pending} == {"pending"}

    await receiver.start()
    try:
        async with running_notify(printers, tmp_path, http, engine) as again:
            await ready(again, printer)
            await wait_for(lambda: len(received(receiver)) >= 2, TOLD_WITHIN, "the missed events")
            await settled(again)
            assert kinds(receiver) == ["print_started", "print_completed"]
            ids = [r.headers["x-kybercore-event-id"] for r in receiver.accepted]
            assert ids == [d.event_id for d in reversed(pending)]
            log = await again.store.deliveries(channel.id)
            assert {d.status for d in log} == {"delivered"}
    finally:
        await receiver.stop()
