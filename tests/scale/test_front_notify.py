"""Notifications on NATS: every front serves them from the shared database, and the front
holding the dispatcher role notifies, once per event, from the views it follows. Real
nats-server, workers, fronts, PostgreSQL, Moonraker and Klippy, and a real webhook
receiver on loopback."""

from __future__ import annotations

import os
import signal
from typing import Any

import httpx
import pytest

from kybercore.sim.stack import PrinterStack
from tests.helpers import KyberCoreServer, wait_for
from tests.notify.live_notify import kinds, received
from tests.notify.receiver import Receiver
from tests.scale.cluster import Cluster
from tests.scale.test_front_queue import PRINT_WITHIN, SHORT, TAKEOVER

pytestmark = pytest.mark.integration

TOLD_WITHIN = 30.0
"""An event reaches the receiver within a second of the holder seeing it: 30× slack."""
HOLDER = "took the dispatcher role"


async def call(api: httpx.AsyncClient, method: str, path: str, **options: Any) -> Any:
    answer = await api.request(method, path, **options)
    assert answer.status_code in (200, 201), answer.text
    return answer.json()


async def all_sent(api: httpx.AsyncClient) -> bool:
    """Whether every delivery in the shared log was sent (or given up)."""
    log = await call(api, "GET", "/api/notifications/deliveries")
    return all(delivery["status"] != "pending" for delivery in log)


def webhook(receiver: Receiver, printer: str, *events: str) -> dict[str, Any]:
    rules = {"events": list(events), "printers": [printer]}
    return {"name": "hook", "kind": "webhook", "target": receiver.url(), "rules": rules}


async def test_a_channel_added_on_any_front_is_served_by_the_one_notifier(
    shared_cluster: Cluster,
    fleet_stacks: list[PrinterStack],
    front_b: KyberCoreServer,
    receiver: Receiver,
) -> None:
    cluster, other = shared_cluster, front_b
    printer = fleet_stacks[0].options.name
    async with (
        httpx.AsyncClient(base_url=cluster.front.url, timeout=60) as a,
        httpx.AsyncClient(base_url=other.url, timeout=60) as b,
    ):
        # Front A (first up) holds the role; front B only serves the API.
        await wait_for(lambda: HOLDER in cluster.front.log.read_text(), TAKEOVER, "A holds")

        # The settings and the channel, set on front B, are front A's too.
        settings = await call(b, "GET", "/api/notifications/settings")
        put = {**settings, "cooldown_s": 0}
        assert (await call(b, "PUT", "/api/notifications/settings", json=put)) == put
        assert (await call(a, "GET", "/api/notifications/settings")) == put
        events = ("print_started", "print_completed")
        channel = await call(
            b, "POST", "/api/notifications/channels", json=webhook(receiver, printer, *events)
        )
        assert [c["id"] for c in await call(a, "GET", "/api/notifications/channels")] == [
            channel["id"]
        ]

        # A test from front B is recorded there and sent by front A's outbox; B answers
        # how it went.
        tested = await call(b, "POST", f"/api/notifications/channels/{channel['id']}/test")
        assert tested["status"] == "delivered", tested
        assert kinds(receiver) == ["test"]

        # Two prints on a worker's printer, back to back. Each is told once (one notifier
        # however many fronts), and the second too: front A uses the cooldown of 0 that
        # front B saved (with the default, 300 s, it would not be told).
        for copy in (1, 2):
            name = f"notify-front-{copy}.gcode"
            started = await call(
                b, "POST", f"/api/printers/{printer}/files",
                files={"file": (name, SHORT)}, data={"start": "true", "confirm": "true"},
            )  # fmt: skip
            assert started["started"], started

            def completed(count: int = copy) -> bool:
                return kinds(receiver).count("print_completed") == count

            await wait_for(completed, PRINT_WITHIN, f"print {copy} told complete")
        await wait_for(lambda: all_sent(a), TOLD_WITHIN, "every delivery sent")

        assert kinds(receiver) == ["test", *events, *events]
        for told in received(receiver)[1:]:
            assert told["printer"]["id"] == printer
            # The picture of the printer's webcam, fetched through its owner.
            assert told["snapshot"]["filename"] == f"{printer}.jpg"
        log = await call(b, "GET", "/api/notifications/deliveries")
        assert sorted(d["kind"] for d in log) == sorted(["test", *events, *events])
        assert HOLDER not in other.log.read_text()


async def test_when_the_notifier_dies_another_front_takes_over_and_tells_a_shutdown_once(
    shared_cluster: Cluster,
    fleet_stacks: list[PrinterStack],
    front_b: KyberCoreServer,
    receiver: Receiver,
) -> None:
    cluster, other = shared_cluster, front_b
    printer = fleet_stacks[1].options.name
    async with httpx.AsyncClient(base_url=other.url, timeout=60) as b:
        await wait_for(lambda: HOLDER in cluster.front.log.read_text(), TAKEOVER, "A holds")
        rules = ("klippy_shutdown", "printer_recovered")
        hook = webhook(receiver, printer, *rules)
        await call(b, "POST", "/api/notifications/channels", json=hook)

        # Front A dies without a word; front B takes the role (a restart: the printers'
        # state then is its baseline) and tells what happens from then on.
        os.kill(cluster.front.pid, signal.SIGKILL)
        await wait_for(lambda: HOLDER in other.log.read_text(), TAKEOVER, "B takes the role")
        action = f"/api/printers/{printer}/actions"
        await call(b, "POST", f"{action}/emergency_stop", json={"confirm": True})
        await wait_for(lambda: "klippy_shutdown" in kinds(receiver), TOLD_WITHIN, "shutdown")
        await call(b, "POST", f"{action}/firmware_restart", json={"confirm": True})
        await wait_for(lambda: "printer_recovered" in kinds(receiver), PRINT_WITHIN, "back")
        await wait_for(lambda: all_sent(b), TOLD_WITHIN, "every delivery sent")

        assert kinds(receiver) == list(rules)
        [shutdown, recovered] = received(receiver)
        assert shutdown["printer"]["id"] == printer
        assert recovered["data"] == {"what": "klippy"}
