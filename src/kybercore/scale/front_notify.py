"""Notifications on NATS: every front serves them, one notifies.

Fronts share the notifications' database (PostgreSQL): channels, the delivery log and the
noise settings, so every front answers ``/api/notifications/*`` from it. Only the front
holding the ``dispatcher`` role (:mod:`.front_queue`, :mod:`.leader`) runs the
:class:`~kybercore.notify.service.NotifyService`: its detector, over the views the front
follows (:class:`FrontNotifyPrinters`), its queue checks and its outbox. One notifier means
one event per transition, however many fronts there are.

What a front that does not run it changes goes through the database, and NATS says so:

- a test message (``POST .../channels/{id}/test``) is recorded there, and
  :data:`WAKE_SUBJECT` wakes the holder's outbox, which sends it; the front that was asked
  reads the outcome back from the database;
- new noise settings are saved there, and :data:`SETTINGS_SUBJECT` has the holder load
  them.

Taking the role is starting the service, as a restart: the printers' state at that moment
is the new baseline, silent. So what happened between the last holder's end and the new
one's start is judged against that baseline: a print that finished in the gap is not told
(the new holder first sees it finished), nor is a printer that went offline in the gap (it
is offline from the start; a print still running is told when it ends). The gap is about
the role's TTL when a holder dies, none when it stops (it hands the role over). Events the
last holder had detected reached the database before it stopped (its stop flushes them);
its outbox's pending deliveries are the new holder's to send.

A printer no worker reports (its slot silent: every worker down, or the slot held by none)
is news of KyberCore itself: past the settings' ``unreported_grace_s`` it is told
(``printer_unreported``; several together, as when a worker dies, in one message), and so
is its return. The grace outlasts a slot moving between workers. A holder cut off from the
broker hears no worker either, but it fences itself within the role's TTL, before the
grace ends: its own silence is not blamed on the workers.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any, Final

from nats.aio.msg import Msg
from nats.aio.subscription import Subscription

from kybercore.errors import KyberCoreError
from kybercore.notify.detector import Observation, observe_view
from kybercore.notify.models import PrinterRef
from kybercore.notify.printers import Observed, OnChange
from kybercore.notify.service import NotifyService
from kybercore.registry.models import PrinterConfig
from kybercore.scale.front import FrontFleet

log = logging.getLogger(__name__)

WAKE_SUBJECT: Final = "kc.notify.wake"
SETTINGS_SUBJECT: Final = "kc.notify.settings"
SNAPSHOT_TIMEOUT: Final = 5.0
"""Seconds a notification's webcam snapshot may take in all (as in one process)."""
_VIEW_KEYS: Final = frozenset({"connection", "klippy_state", "klippy_message", "runout"})
_JOB_KEYS: Final = frozenset({"state", "filename", "message", "layer"})


def may_change_observation(patch: Mapping[str, Any] | None) -> bool:
    """Whether a patch to a view touches what an observation reads
    (:func:`~kybercore.notify.detector.observe_view`); a whole new view (None) may."""
    if patch is None or not _VIEW_KEYS.isdisjoint(patch):
        return True
    job = patch.get("job")
    return isinstance(job, dict) and not _JOB_KEYS.isdisjoint(job)


class FrontNotifyPrinters:
    """The printers as notifications read them on a front: the views it follows, and a
    webcam's snapshot through the printer's owner.

    Two things on a front are no news of the printer itself, and are read as the
    observation before them: a view marked stale (its owner went silent; the owner's last
    view is read instead, marked not ``reported``: news of KyberCore, told past a grace
    period), and ``connecting`` once the printer was seen otherwise (a new owner's session
    starting, when a slot moves between workers; a front cannot tell it from the first
    connection of a session for other reasons, which then reads as the state before it)."""

    def __init__(self, fleet: FrontFleet) -> None:
        self._fleet = fleet
        self._last: dict[str, Observation] = {}
        """Each printer's last observation that was not ``connecting``."""

    def all(self) -> list[Observed]:
        """Every printer of the registry, as its view stands now."""
        self.ids()  # forgets the printers gone
        return [self._observed(config) for config in self._fleet.configs()]

    def ids(self) -> set[str]:
        """The ids of every printer of the registry."""
        present = {config.id for config in self._fleet.configs()}
        self._last = {pid: seen for pid, seen in self._last.items() if pid in present}
        return present

    def get(self, printer_id: str) -> Observed:
        """One printer as its view stands now (UnknownPrinter when not in the registry)."""
        return self._observed(self._fleet.config(printer_id))

    def listen(self, on_change: OnChange) -> Callable[[], None]:
        """Call ``on_change`` for the views' changes that touch an observation (see
        :func:`may_change_observation`); returns the way to stop."""

        def hear(printer_id: str, patch: dict[str, Any] | None) -> None:
            if may_change_observation(patch):
                on_change(printer_id)

        return self._fleet.watch(hear)

    async def snapshot(self, printer_id: str) -> bytes | None:
        """A JPEG from the printer's first enabled webcam that gives one, fetched by its
        owner (``camera_snapshot``), as :func:`~kybercore.notify.snapshot.take_snapshot`
        does in one process; None otherwise. Never raises."""
        try:
            async with asyncio.timeout(SNAPSHOT_TIMEOUT):
                if self._fleet.current_view(printer_id).get("connection") != "online":
                    return None  # an offline printer's webcam is as far away as its Moonraker
                for camera in await self._fleet.cameras(printer_id):
                    with contextlib.suppress(KyberCoreError):  # no JPEG: try the next one
                        return (await self._fleet.camera_snapshot(printer_id, camera.name)).content
        except Exception as exc:  # a snapshot is optional: whatever went wrong, send without
            log.debug("%s: no snapshot (%s: %s)", printer_id, type(exc).__name__, exc)
        return None

    def _observed(self, config: PrinterConfig) -> Observed:
        # The owner's last view, not the one marked stale (current_view's when none came).
        view = self._fleet.copy.views.get(config.id) or self._fleet.current_view(config.id)
        observation = observe_view(view)
        if observation.connection == "connecting" and config.id in self._last:
            observation = self._last[config.id]
        else:
            self._last[config.id] = observation
        if not self._fleet.reported(config.id):
            observation = replace(observation, reported=False)
        return Observed(PrinterRef.of(config), observation)


class NatsPeers:
    """The other fronts, as :class:`~kybercore.notify.service.Peers`: told over NATS."""

    def __init__(self, fleet: FrontFleet) -> None:
        self._fleet = fleet

    async def recorded(self) -> None:
        """Wake the running notifier's outbox (:data:`WAKE_SUBJECT`)."""
        await self._fleet.nc.publish(WAKE_SUBJECT, b"")

    async def settings_saved(self) -> None:
        """Have the running notifier load the settings (:data:`SETTINGS_SUBJECT`)."""
        await self._fleet.nc.publish(SETTINGS_SUBJECT, b"")


class FrontNotify:
    """One front's part in the notifications, besides running the service while it holds
    the role: hearing what the other fronts changed (see the module docstring)."""

    def __init__(self, fleet: FrontFleet, notify: NotifyService) -> None:
        self._fleet = fleet
        self._notify = notify
        self._subscriptions: list[Subscription] = []

    async def start(self) -> None:
        """Hear the other fronts' wake-ups and settings."""
        nc = self._fleet.nc
        self._subscriptions = [
            await nc.subscribe(WAKE_SUBJECT, cb=self._woken),
            await nc.subscribe(SETTINGS_SUBJECT, cb=self._settings),
        ]

    async def stop(self) -> None:
        """Stop hearing them."""
        for subscription in self._subscriptions:
            with contextlib.suppress(Exception):  # the broker may be gone already
                await subscription.unsubscribe()
        self._subscriptions = []

    async def _woken(self, _msg: Msg) -> None:
        # Whether or not the service runs here: a stopped outbox looks anyway when started.
        self._notify.outbox.wake()

    async def _settings(self, _msg: Msg) -> None:
        try:
            await self._notify.reload_settings()
        except Exception as exc:  # the database away: the next start loads them anyway
            log.warning("notifications: could not load the new settings: %s", exc)
