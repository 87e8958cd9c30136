"""Bad input and bad peers become typed errors that say what to do; never None."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

import httpx
import pytest

from kybercore.errors import (
    KlippyNotReady,
    MoonrakerRpcError,
    PrinterTimeout,
    PrinterUnreachable,
)
from kybercore.moonraker.client import MoonrakerClient
from kybercore.sim.stack import PrinterStack, free_port


async def test_refused_connection(http: httpx.AsyncClient) -> None:
    client = MoonrakerClient(f"http://127.0.0.1:{free_port()}", http, name="p")
    with pytest.raises(PrinterUnreachable, match=r"connection refused .* Is Moonraker running"):
        await client.server_info()


async def test_unknown_host_name(http: httpx.AsyncClient) -> None:
    client = MoonrakerClient("http://no-such-printer.invalid:7125", http, name="p")
    with pytest.raises(PrinterUnreachable, match="cannot be resolved"):
        await client.printer_info()


async def _serve(reply: bytes | None) -> tuple[asyncio.Server, str]:
    """FAULT-INJECTION stand-in, not Moonraker: a TCP peer that answers every request with
    fixed bytes, or accepts and never answers (``reply=None``), as a hung host does."""

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        await reader.readuntil(b"\r\n\r\n")
        if reply is None:
            await asyncio.sleep(3600)  # stand-in: simulates a host that never answers
        writer.write(reply or b"")
        await writer.drain()
        writer.close()

    server = await asyncio.start_server(handle, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    return server, f"http://127.0.0.1:{port}"


async def test_a_body_that_is_not_json(http: httpx.AsyncClient) -> None:
    html = b"<html>router login</html>"
    reply = b"HTTP/1.1 200 OK\r\nContent-Type: text/html\r\nContent-Length: %d\r\n\r\n%s" % (
        len(html),
        html,
    )
    server, url = await _serve(reply)
    try:
        client = MoonrakerClient(url, http, name="p")
        with pytest.raises(MoonrakerRpcError, match=r"not JSON\. Is the URL really a Moonraker"):
            await client.server_info()
    finally:
        server.close()


async def test_a_host_that_never_answers_times_out_quickly() -> None:
    server, url = await _serve(None)
    try:
        async with httpx.AsyncClient(timeout=httpx.Timeout(0.5), trust_env=False) as quick:
            client = MoonrakerClient(url, quick, name="p")
            started = time.monotonic()
            with pytest.raises(PrinterTimeout, match="did not answer"):
                await client.server_info()
            # Promise: the client's timeout (0.5 s here) is kept. Idle: 0.50 s; 5x slack.
            assert time.monotonic() - started < 2.5
    finally:
        server.close()


@pytest.mark.integration
async def test_printer_endpoints_before_klippy_ever_connects(
    start_stack: Callable[..., PrinterStack], http: httpx.AsyncClient
) -> None:
    stack = start_stack("noklippy", with_klippy=False)
    try:
        client = MoonrakerClient(stack.url, http, name="noklippy")
        for _ in range(100):
            try:
                info = await client.server_info()
                break
            except PrinterUnreachable:
                await asyncio.sleep(0.1)  # poll: wait for Moonraker to listen, 100 tries
        assert info["klippy_connected"] is False
        with pytest.raises(KlippyNotReady, match="Klippy is not connected"):
            await client.printer_info()
        with pytest.raises(KlippyNotReady):
            await client.print_pause()
    finally:
        stack.stop()
