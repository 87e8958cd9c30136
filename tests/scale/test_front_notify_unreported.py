"""Notifications on NATS when KyberCore itself loses sight of the printers: every worker
dies, and the notifying front tells that no worker reports them (one message for all), then
that a worker reports them again. Real nats-server, workers, front, PostgreSQL, Moonraker and
Klippy, and a real webhook receiver on loopback."""

from __future__ import annotations

import asyncio
import signal

import httpx
import pytest

from kybercore.scale.follow import STALE_SECONDS
from kybercore.sim.stack import PrinterStack
from tests.helpers import wait_for
from tests.notify.live_notify import kinds, received
from tests.notify.receiver import Receiver
from tests.scale.cluster import SETTLE, Cluster
from tests.scale.test_front_notify import HOLDER, TOLD_WITHIN, all_sent, call
from tests.scale.test_front_queue import TAKEOVER

pytestmark = pytest.mark.integration

GRACE = 3.0
"""The test's grace (the default, 30 s, outlasts a worker's failover)."""
FOLD = 10.0
"""The fold window: the workers' printers go stale within about a second and a half of
each other (their heartbeats, the front's checks, the notifier's ticks), well inside it."""
KINDS = ["printer_unreported", "printer_recovered"]


def told_about(receiver: Receiver, kind: str) -> set[str]:
    """The printers the messages of ``kind`` received so far speak for."""
    return {pid for body in received(receiver, kind=kind) for pid in body["data"]["printers"]}


async def test_when_no_worker_reports_the_printers_the_front_tells_it_once_and_their_return(
    shared_cluster: Cluster, fleet_stacks: list[PrinterStack], receiver: Receiver
) -> None:
    cluster = shared_cluster
    printers = {stack.options.name for stack in fleet_stacks}
    async with httpx.AsyncClient(base_url=cluster.front.url, timeout=60) as api:
        await wait_for(lambda: HOLDER in cluster.front.log.read_text(), TAKEOVER, "the role")
        settings = await call(api, "GET", "/api/notifications/settings")
        tuned = {**settings, "unreported_grace_s": GRACE, "fold_window_s": FOLD}
        await call(api, "PUT", "/api/notifications/settings", json=tuned)
        hook = {"name": "hook", "kind": "webhook", "target": receiver.url(),
                "rules": {"events": KINDS, "language": "en"}}  # fmt: skip
        await call(api, "POST", "/api/notifications/channels", json=hook)

        # Every worker dies: the front still runs, and no one reports any printer.
        for worker in cluster.workers.values():
            worker.signal(signal.SIGKILL)
        for worker in cluster.workers.values():
            await asyncio.to_thread(worker.proc.wait, 10)
        lost_within = STALE_SECONDS + GRACE + FOLD + TOLD_WITHIN
        await wait_for(
            lambda: told_about(receiver, "printer_unreported") == printers,
            lost_within, "told that no worker reports the printers",
        )  # fmt: skip
        await wait_for(lambda: all_sent(api), TOLD_WITHIN, "every delivery sent")
        [lost] = received(receiver)
        assert (lost["type"], lost["printer"], lost["severity"]) == (
            "printer_unreported", None, "critical",
        )  # fmt: skip
        assert lost["data"]["count"] == len(printers)
        assert "kybercore ingest" in lost["message"], lost["message"]

        # A worker is started again and takes every slot: one message says so.
        cluster.worker("w3")
        await wait_for(
            lambda: told_about(receiver, "printer_recovered") == printers,
            SETTLE + FOLD + TOLD_WITHIN, "told that a worker reports them again",
        )  # fmt: skip
        await wait_for(lambda: all_sent(api), TOLD_WITHIN, "every delivery sent")
        assert kinds(receiver) == KINDS
        back = received(receiver)[1]
        assert (back["printer"], back["data"]["what"]) == (None, "worker")
