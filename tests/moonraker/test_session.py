"""The long-lived WebSocket session, against real Moonraker + Klippy printers."""

from __future__ import annotations

import asyncio
import functools
import time
from collections.abc import AsyncIterator, Callable
from typing import Any

import httpx
import picows
import pytest

from kybercore.errors import MoonrakerRpcError, PrinterAuthFailed, PrinterUnreachable
from kybercore.moonraker.client import MoonrakerClient
from kybercore.moonraker.events import (
    ConnectionChanged,
    KlippyChanged,
    SessionEvent,
    StatusDelta,
    StatusSnapshot,
)
from kybercore.sim.stack import PrinterStack
from tests.helpers import wait_for

pytestmark = pytest.mark.integration

FAIL_WITHIN = 3.0
"""Promise: pending calls fail at once when Moonraker goes (not at the G-code's end or a
timeout). Idle: 0.10-0.22 s from the stop command, most of it Moonraker's own exit (14x);
measured by bench/promises.py."""


class Recorder:
    """Collects a session's events and answers questions about them."""

    def __init__(self) -> None:
        self.events: list[SessionEvent] = []

    def __call__(self, event: SessionEvent) -> None:
        self.events.append(event)

    def of(self, kind: type[SessionEvent]) -> list[SessionEvent]:
        return [e for e in self.events if isinstance(e, kind)]

    def klippy(self) -> list[str]:
        return [e.state for e in self.events if isinstance(e, KlippyChanged)]

    def connection(self) -> list[str]:
        return [e.connection for e in self.events if isinstance(e, ConnectionChanged)]


@pytest.fixture
async def live(
    http: httpx.AsyncClient,
) -> AsyncIterator[Callable[..., tuple[MoonrakerClient, Recorder]]]:
    """Start sessions for a test and close them afterwards."""
    clients: list[MoonrakerClient] = []

    def open_session(
        stack: PrinterStack, *, via: httpx.AsyncClient | None = None, **options: Any
    ) -> tuple[MoonrakerClient, Recorder]:
        recorder = Recorder()
        client = MoonrakerClient(
            stack.url, via or http, name=stack.options.name, on_event=recorder, **options
        )
        client.start()
        clients.append(client)
        return client, recorder

    yield open_session
    for client in clients:
        await client.close()


async def test_subscribes_and_streams_deltas(
    printer: PrinterStack, live: Callable[..., tuple[MoonrakerClient, Recorder]]
) -> None:
    client, rec = live(printer)
    await wait_for(lambda: bool(rec.of(StatusSnapshot)), what="a status snapshot")
    assert rec.connection()[0] == "online"
    assert rec.klippy()[-1] == "ready"
    snapshot = rec.of(StatusSnapshot)[0]
    assert isinstance(snapshot, StatusSnapshot)
    assert {"toolhead", "extruder", "heater_bed", "print_stats", "webhooks"} <= set(snapshot.status)
    await client.gcode_script("M104 S60")
    try:
        await wait_for(
            lambda: any(
                isinstance(e, StatusDelta)
                and e.delta.get("extruder", {}).get("temperature", 0) > 30
                for e in rec.events
            ),
            timeout=20,
            what="the hotend to warm up in the status deltas",
        )
    finally:
        await client.gcode_script("M104 S0")


async def test_rpc_error_is_typed(
    printer: PrinterStack, live: Callable[..., tuple[MoonrakerClient, Recorder]]
) -> None:
    client, rec = live(printer)
    await wait_for(lambda: bool(rec.of(StatusSnapshot)), what="a status snapshot")
    with pytest.raises(MoonrakerRpcError) as error:
        await client.call("server.files.metadata", {"filename": "does-not-exist.gcode"})
    assert "Metadata not available" in error.value.detail
    with pytest.raises(MoonrakerRpcError) as unknown:
        await client.call("server.no_such_method")
    assert unknown.value.rpc_code == -32601


async def test_klippy_shutdown_keeps_the_socket_and_ready_resubscribes(
    own_printer: PrinterStack, live: Callable[..., tuple[MoonrakerClient, Recorder]]
) -> None:
    client, rec = live(own_printer)
    await wait_for(lambda: bool(rec.of(StatusSnapshot)), what="a status snapshot")
    await client.emergency_stop()
    await wait_for(lambda: rec.klippy()[-1] == "shutdown", what="Klippy shutdown")
    assert rec.connection() == ["online"], "the socket must stay up through a Klippy shutdown"
    snapshots = len(rec.of(StatusSnapshot))
    await client.firmware_restart()
    await wait_for(lambda: rec.klippy()[-1] == "ready", timeout=20, what="Klippy ready again")
    await wait_for(lambda: len(rec.of(StatusSnapshot)) > snapshots, what="a new subscription")
    assert rec.connection() == ["online"]
    # The fresh subscription streams again.
    marker = len(rec.events)
    await client.gcode_script("G28")
    await wait_for(
        lambda: any(
            isinstance(e, StatusDelta) and "toolhead" in e.delta for e in rec.events[marker:]
        ),
        what="toolhead deltas after the restart",
    )


async def test_moonraker_restart_fails_pending_calls_and_reconnects_by_itself(
    own_printer: PrinterStack, live: Callable[..., tuple[MoonrakerClient, Recorder]]
) -> None:
    client, rec = live(own_printer)
    await wait_for(lambda: bool(rec.of(StatusSnapshot)), what="a status snapshot")
    await client.gcode_script("G28")
    ws_call = asyncio.create_task(client.call("printer.gcode.script", {"script": "G4 P6000"}))
    http_call = asyncio.create_task(client.gcode_script("G4 P6000"))

    async def both_received() -> bool:
        """Moonraker stores a script in its console as it receives it."""
        store = await client.gcode_store(count=20)
        return [e["message"] for e in store].count("G4 P6000") == 2

    # Both calls are in flight when Moonraker goes, not failed on the not-connected path.
    await wait_for(both_received, what="Moonraker to receive both calls")
    assert not ws_call.done()
    assert not http_call.done()
    stopped_at = time.monotonic()
    own_printer.stop_moonraker()
    with pytest.raises(PrinterUnreachable, match="lost the connection"):
        await ws_call
    with pytest.raises(PrinterUnreachable):
        await http_call
    failed_after = time.monotonic() - stopped_at
    assert failed_after < FAIL_WITHIN, f"pending calls failed after {failed_after:.1f} s"
    await wait_for(lambda: rec.connection()[-1] == "offline", what="offline")
    with pytest.raises(PrinterUnreachable):
        await client.call("server.info")

    snapshots = len(rec.of(StatusSnapshot))
    own_printer.start_moonraker()
    await wait_for(lambda: len(rec.of(StatusSnapshot)) > snapshots, timeout=30, what="resubscribe")
    assert rec.connection()[-1] == "online"
    marker = len(rec.events)
    await client.gcode_script("G1 X20 F3000")
    await wait_for(
        lambda: any(isinstance(e, StatusDelta) for e in rec.events[marker:]),
        what="a status update after reconnecting",
    )


async def test_api_key_over_http_and_websocket_from_an_untrusted_address(
    start_stack: Callable[..., PrinterStack], live: Callable[..., tuple[MoonrakerClient, Recorder]]
) -> None:
    # Moonraker trusts 127.0.0.1 only; our client talks from 127.0.0.2, so it must authenticate.
    stack = start_stack("auth", trusted_clients=("127.0.0.1/32",))
    try:
        async with httpx.AsyncClient(trust_env=False) as trusted:
            response = await trusted.get(f"{stack.url}/access/api_key")
            key = response.json()["result"]
        transport = httpx.AsyncHTTPTransport(local_address="127.0.0.2")
        connect = functools.partial(picows.ws_connect, local_addr=("127.0.0.2", 0))
        async with httpx.AsyncClient(transport=transport, trust_env=False) as untrusted:
            anonymous = MoonrakerClient(stack.url, untrusted, name="auth")
            with pytest.raises(PrinterAuthFailed):
                await anonymous.server_info()

            good, good_rec = live(stack, via=untrusted, api_key=key, connect=connect)
            assert (await good.server_info())["klippy_state"] == "ready"
            await wait_for(
                lambda: bool(good_rec.of(StatusSnapshot)), what="an authenticated subscription"
            )

            bad, bad_rec = live(stack, via=untrusted, api_key="wrong", connect=connect)
            with pytest.raises(PrinterAuthFailed, match="API key"):
                await bad.server_info()
            await wait_for(lambda: "auth_failed" in bad_rec.connection(), what="auth_failed")
            assert not bad_rec.of(StatusSnapshot)
    finally:
        stack.stop()


async def test_a_second_client_with_the_same_agent_name_still_subscribes(
    printer: PrinterStack, live: Callable[..., tuple[MoonrakerClient, Recorder]]
) -> None:
    _first, first_rec = live(printer, client_name="KyberCore twin")
    await wait_for(lambda: bool(first_rec.of(StatusSnapshot)), what="first subscription")
    _second, second_rec = live(printer, client_name="KyberCore twin")
    await wait_for(lambda: bool(second_rec.of(StatusSnapshot)), what="second subscription")
    assert second_rec.connection() == ["online"]
