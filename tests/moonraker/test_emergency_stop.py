"""Emergency stop takes the open WebSocket first, HTTP only as the fallback: real Moonraker +
Klippy, with every HTTP request the client makes counted."""

from __future__ import annotations

from collections.abc import AsyncIterator, Mapping
from typing import Any

import httpx
import pytest

from kybercore.errors import PrinterUnreachable
from kybercore.moonraker.client import MoonrakerClient
from kybercore.moonraker.events import KlippyChanged, SessionEvent
from kybercore.sim.stack import PrinterStack
from tests.helpers import wait_for

pytestmark = pytest.mark.integration

E_STOP = "/printer/emergency_stop"


class Counted:
    """A shared HTTP client that records the path of every request it sends."""

    def __init__(self) -> None:
        self.paths: list[str] = []

    async def record(self, request: httpx.Request) -> None:
        self.paths.append(request.url.path)


@pytest.fixture
async def counted() -> AsyncIterator[tuple[httpx.AsyncClient, Counted]]:
    counter = Counted()
    async with httpx.AsyncClient(
        trust_env=False, timeout=30, event_hooks={"request": [counter.record]}
    ) as http:
        yield http, counter


async def test_e_stop_goes_over_the_open_socket_and_over_http_without_one(
    own_printer: PrinterStack, counted: tuple[httpx.AsyncClient, Counted]
) -> None:
    http, counter = counted
    states: list[str] = []

    def on_event(event: SessionEvent) -> None:
        if isinstance(event, KlippyChanged):
            states.append(event.state)

    client = MoonrakerClient(own_printer.url, http, name="own", on_event=on_event)
    client.start()
    try:
        await wait_for(lambda: states[-1:] == ["ready"], what="the session ready")
        await client.emergency_stop()
        assert E_STOP not in counter.paths, "the e-stop went over HTTP with a socket open"
        await wait_for(lambda: states[-1] == "shutdown", what="Klippy shut down")
        await client.firmware_restart()
        await wait_for(lambda: states[-1] == "ready", timeout=30, what="Klippy ready again")
    finally:
        await client.close()

    # No session: HTTP it is, and it works.
    assert not client.session.connected
    await client.emergency_stop()
    assert counter.paths.count(E_STOP) == 1
    await wait_for(
        lambda: _klippy(client, "shutdown"), what="Klippy shut down by the e-stop over HTTP"
    )


async def _klippy(client: MoonrakerClient, state: str) -> bool:
    return (await client.server_info())["klippy_state"] == state


class FakeSession:
    """Unit-level fake (no traffic): a socket that is open until the call over it fails,
    dropped (the link went) or still open (Moonraker stopped answering)."""

    def __init__(self, drops: bool) -> None:
        self.open = True
        self.drops = drops
        self.sent: list[str] = []

    async def call(
        self, method: str, params: Mapping[str, Any] | None = None, timeout: float = 10.0
    ) -> Any:
        self.sent.append(method)
        self.open = not self.drops
        raise PrinterUnreachable("lost the connection to Moonraker", printer="p")


@pytest.mark.parametrize("drops", [True, False], ids=["socket dropped", "Moonraker silent"])
async def test_e_stop_falls_back_to_http_only_when_the_socket_dropped(
    drops: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A dropped socket: the e-stop is sent again over HTTP (twice is harmless). An open one
    on which Moonraker stopped answering: HTTP would not be answered either; fail at once."""
    async with httpx.AsyncClient() as http:
        client = MoonrakerClient("http://127.0.0.1:9", http, name="p")
        fake = FakeSession(drops)

        async def over_http(method: str, path: str, **_kwargs: Any) -> Any:
            fake.sent.append(f"{method} {path}")
            return "ok"

        session_type = type(client.session)
        monkeypatch.setattr(session_type, "connected", property(lambda _self: fake.open))
        monkeypatch.setattr(client.session, "call", fake.call)
        monkeypatch.setattr(client._channel, "request", over_http)
        if drops:
            await client.emergency_stop()
            assert fake.sent == ["printer.emergency_stop", f"POST {E_STOP}"]
        else:
            with pytest.raises(PrinterUnreachable):
                await client.emergency_stop()
            assert fake.sent == ["printer.emergency_stop"]
