"""Connection and Klippy state changes reach the log at INFO, one line each, named by printer
and reason, rate-limited per printer and state."""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator

import httpx
import pytest

from kybercore.moonraker.client import MoonrakerClient
from kybercore.moonraker.events import KlippyChanged, SessionEvent
from kybercore.moonraker.statelog import StateLog
from kybercore.sim.stack import PrinterStack
from tests.helpers import wait_for

LOGGER = "kybercore.moonraker.statelog"


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [
        r.getMessage() for r in caplog.records if r.name == LOGGER and r.levelno == logging.INFO
    ]


def test_one_line_per_state_per_window_and_the_rest_counted(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger=LOGGER)
    clock = Clock()
    states = StateLog("voron-1", every=60.0, clock=clock)
    for _ in range(40):  # a night of outages, one every 10 s
        states.connection("offline", "connection refused by 10.0.0.5:7125")
        clock.now += 5
        states.connection("online")
        clock.now += 5
    logged = lines(caplog)
    assert logged[:2] == [
        "voron-1: Moonraker offline: connection refused by 10.0.0.5:7125",
        "voron-1: Moonraker online",
    ]
    # 400 s: one line per state per minute, each saying how many it stands for.
    assert len(logged) == 2 * 7
    assert logged[2] == (
        "voron-1: Moonraker offline: connection refused by 10.0.0.5:7125 "
        "(and 5 more times in the last 60 s)"
    )
    assert sum(1 for line in logged if "online" in line) == 7


def test_klippy_changes_name_the_state_before(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger=LOGGER)
    states = StateLog("p1")
    states.klippy("shutdown", "ready", "Shutdown due to webhooks request")
    states.klippy("ready", "shutdown")
    assert lines(caplog) == [
        "p1: Klippy shutdown (was ready): Shutdown due to webhooks request",
        "p1: Klippy ready (was shutdown)",
    ]


def test_printers_are_limited_apart(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger=LOGGER)
    clock = Clock()
    a, b = StateLog("a", clock=clock), StateLog("b", clock=clock)
    a.connection("offline", "x")
    b.connection("offline", "x")
    assert lines(caplog) == ["a: Moonraker offline: x", "b: Moonraker offline: x"]


@pytest.fixture
async def watched(
    own_printer: PrinterStack, http: httpx.AsyncClient
) -> AsyncIterator[tuple[MoonrakerClient, list[SessionEvent]]]:
    events: list[SessionEvent] = []
    client = MoonrakerClient(own_printer.url, http, name="own", on_event=events.append)
    client.start()
    yield client, events
    await client.close()


def klippy(events: list[SessionEvent]) -> str:
    states = [e.state for e in events if isinstance(e, KlippyChanged)]
    return states[-1] if states else ""


@pytest.mark.integration
async def test_a_moonraker_restart_and_an_e_stop_are_in_the_log(
    own_printer: PrinterStack,
    watched: tuple[MoonrakerClient, list[SessionEvent]],
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger=LOGGER)
    client, events = watched
    await wait_for(lambda: klippy(events) == "ready", what="the first ready")
    own_printer.stop_moonraker()
    await wait_for(lambda: client.session.connection == "offline", what="offline")
    own_printer.start_moonraker()
    await wait_for(lambda: klippy(events) == "ready", timeout=30, what="ready again")
    await client.emergency_stop()
    await wait_for(lambda: klippy(events) == "shutdown", what="Klippy shut down")
    logged = lines(caplog)
    assert logged[:3] == [
        "own: Moonraker online",
        "own: Klippy ready (was disconnected)",
        "own: Klippy disconnected (was ready)",
    ]
    offline = [line for line in logged if line.startswith("own: Moonraker offline: ")]
    assert len(offline) == 1
    assert "Moonraker closed the connection" in offline[0] or "dropped" in offline[0]
    # Back: the same states again, within the minute: held back and counted, not repeated.
    assert logged.count("own: Moonraker online") == 1
    assert logged[-1] == "own: Klippy shutdown (was ready)"
