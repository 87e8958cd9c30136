"""Fixtures of the notification tests: the database on SQLite and PostgreSQL (from
tests/jobs), a store on it, a loopback receiver, and events and channels to record."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

import pytest
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.notify.models import EventKind, FleetEvent, PrinterRef
from kybercore.notify.records import Channel
from kybercore.notify.rules import ChannelRules
from kybercore.notify.store import NotifyStore
from tests.jobs.conftest import database, database_url

__all__ = ["database", "database_url"]

SECRET = "whsec_test_0123456789"


def printer_ref(printer_id: str) -> PrinterRef:
    """A printer as an event names it."""
    return PrinterRef(id=printer_id, name=f"Printer {printer_id}", location="Room B", tags=())


def fleet_event(
    kind: EventKind = "print_failed", printer: str | None = "a", **params: Any
) -> FleetEvent:
    """An event happening now (``printer`` None: a fleet-wide one)."""
    if not params:
        params = {"filename": "cube.gcode", "message": "Heater extruder not heating"}
    return FleetEvent(
        kind=kind,
        at=datetime.now(UTC),
        printer=printer_ref(printer) if printer is not None else None,
        params=params,
    )


@pytest.fixture
def store(database: AsyncEngine) -> NotifyStore:
    """The notification store on the test's database."""
    return NotifyStore(database)


async def add_webhook(
    store: NotifyStore,
    url: str,
    *,
    secret: str | None = SECRET,
    name: str = "hook",
    **rules: Any,
) -> Channel:
    """A webhook channel to ``url`` (``rules``: ChannelRules fields)."""
    return await store.add_channel(
        name=name,
        kind="webhook",
        target=url,
        secret=secret,
        rules=ChannelRules(**rules),
        enabled=True,
        user="ana",
    )
