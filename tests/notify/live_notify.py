"""KyberCore's fleet, queue and notifications over real printers (or unreachable ones) and a
real database, for the notification service's tests; and what a webhook receiver got."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import httpx
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.fleet.service import FleetService
from kybercore.jobs.files import JobFiles
from kybercore.jobs.service import QueueService
from kybercore.jobs.store import JobStore
from kybercore.notify.models import NoiseSettings
from kybercore.notify.printers import FleetNotifyPrinters
from kybercore.notify.records import Channel
from kybercore.notify.rules import ChannelRules
from kybercore.notify.service import NotifyService
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import PrinterRegistry, write_printers
from tests.notify.receiver import Receiver

SECRET = "webhook-secret-for-the-tests-0123456789"
FAST = NoiseSettings(
    cooldown_s=0.0, fold_window_s=0.3, storm_threshold=3, plate_wait_s=0.0, job_blocked_s=0.0
)
"""Settings that let the tests run in seconds: no cooldown, a short fold window."""
RETRY: dict[str, float] = {"first_retry": 0.2, "max_retry": 1.0}


@contextlib.asynccontextmanager
async def running_notify(
    printers: list[PrinterConfig],
    folder: Path,
    http: httpx.AsyncClient,
    engine: AsyncEngine,
    settings: NoiseSettings = FAST,
    **options: Any,
) -> AsyncIterator[NotifyService]:
    """The fleet (started), its queue (not dispatching: the tests drive the store) and the
    notification service over ``printers``, with ``settings`` stored before it starts.
    Everything stops on exit, as when KyberCore stops."""
    path = folder / "printers.json"
    write_printers(path, printers)
    fleet = FleetService(PrinterRegistry(path), http)
    queue = QueueService(fleet, JobStore(engine), JobFiles(folder / "files"))
    options = {"tick": 0.05, "queue_poll": 0.1, "outbox_options": RETRY, **options}
    notify = NotifyService(FleetNotifyPrinters(fleet, http), queue, engine, http, **options)
    await notify.store.save_settings(settings)
    await fleet.start()
    try:
        await notify.start()
        try:
            yield notify
        finally:
            await notify.stop()
    finally:
        await fleet.stop()


async def add_webhook(
    notify: NotifyService, receiver: Receiver, path: str = "/hook", **rules: Any
) -> Channel:
    """A webhook channel to ``receiver`` at ``path``, signed with :data:`SECRET`."""
    return await notify.store.add_channel(
        name=f"hook {path}",
        kind="webhook",
        target=receiver.url(path),
        secret=SECRET,
        rules=ChannelRules(**rules),
        enabled=True,
        user="test",
    )


def received(receiver: Receiver, path: str = "/hook", kind: str | None = None) -> list[Any]:
    """The JSON bodies ``receiver`` accepted at ``path`` (of ``kind`` only, if given)."""
    bodies = [r.json() for r in receiver.accepted if r.method == "POST" and r.path == path]
    return [b for b in bodies if kind is None or b["type"] == kind]


def kinds(receiver: Receiver, path: str = "/hook") -> list[str]:
    """The event types ``receiver`` accepted at ``path``, in order."""
    return [body["type"] for body in received(receiver, path)]
