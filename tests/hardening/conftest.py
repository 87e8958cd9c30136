"""Fixtures shared by the upstream-fault tests."""

from __future__ import annotations

from collections.abc import AsyncIterator, Awaitable, Callable

import pytest

from kybercore.moonraker import session as moonraker_session
from tests.hardening.faulty_moonraker import FaultyMoonraker

FAST_PING_INTERVAL = 0.5
FAST_PING_TIMEOUT = 0.5
FAST_OPEN_TIMEOUT = 0.5

StartStandin = Callable[..., Awaitable[FaultyMoonraker]]


@pytest.fixture
def fast_timeouts(monkeypatch: pytest.MonkeyPatch) -> None:
    """Keepalive and open timeouts of 0.5 s (CLOSE_TIMEOUT keeps its production value)."""
    monkeypatch.setattr(moonraker_session, "PING_INTERVAL", FAST_PING_INTERVAL)
    monkeypatch.setattr(moonraker_session, "PING_TIMEOUT", FAST_PING_TIMEOUT)
    monkeypatch.setattr(moonraker_session, "OPEN_TIMEOUT", FAST_OPEN_TIMEOUT)


@pytest.fixture
async def standins() -> AsyncIterator[StartStandin]:
    """Start FAULT-INJECTION stand-ins by scenario; all are stopped after the test."""
    started: list[FaultyMoonraker] = []

    async def start(scenario: str, **options: float) -> FaultyMoonraker:
        standin = FaultyMoonraker(scenario, **options)  # type: ignore[arg-type]
        await standin.start()
        started.append(standin)
        return standin

    yield start
    for standin in started:
        await standin.stop()
