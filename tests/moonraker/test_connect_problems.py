"""Every way a connection to Moonraker can fail reads as a sentence naming the cause.

Causes that cannot be produced on loopback (no route, an unreachable network, a DNS
failure) are built as the exception chains httpx/anyio and asyncio raise for them; nothing
here sends traffic anywhere but 127.0.0.1.
"""

from __future__ import annotations

import asyncio
import errno
import re
import socket
import ssl

import httpx
import pytest

from kybercore.errors import PrinterTimeout, PrinterUnreachable
from kybercore.moonraker.backoff import Backoff
from kybercore.moonraker.client import MoonrakerClient
from kybercore.moonraker.events import ConnectionChanged, SessionEvent
from kybercore.moonraker.reach import connect_problem, connection_refused
from tests.helpers import wait_for

URL = "http://127.0.0.1:7125"


def anyio_failure(cause: BaseException) -> httpx.ConnectError:
    """What httpx raises when anyio's connect fails: a ConnectError from anyio's "All
    connection attempts failed", itself raised from the socket's error."""
    anyio_error = OSError("All connection attempts failed")
    anyio_error.__cause__ = cause
    error = httpx.ConnectError(str(anyio_error))
    error.__cause__ = anyio_error
    return error


def connect_call_failed(code: int, address: str = "127.0.0.1") -> OSError:
    """asyncio's own wording for a failed connect(), as ``sock_connect`` raises it."""
    return OSError(code, f"Connect call failed ('{address}', 7125)")


CASES: list[tuple[str, BaseException, str]] = [
    (
        "refused",
        connect_call_failed(errno.ECONNREFUSED),
        r"connection refused by .*Is Moonraker running",
    ),
    ("no route", connect_call_failed(errno.EHOSTUNREACH), r"no route to .*switched off"),
    ("host down", connect_call_failed(errno.EHOSTDOWN), r"no route to .*switched off"),
    ("network", connect_call_failed(errno.ENETUNREACH), r"network .* is unreachable from"),
    (
        "dns",
        socket.gaierror(socket.EAI_NONAME, "Name or service not known"),
        r"host name in .* cannot be resolved",
    ),
    (
        "dns, temporary",
        socket.gaierror(socket.EAI_AGAIN, "Temporary failure in name resolution"),
        r"host name in .* cannot be resolved",
    ),
    (
        "tls",
        ssl.SSLCertVerificationError(
            1,
            "[SSL: CERTIFICATE_VERIFY_FAILED] certificate verify failed: self-signed "
            "certificate (_ssl.c:1006)",
        ),
        r"TLS .*handshake with .* failed \(certificate verify failed",
    ),
    ("timeout", TimeoutError(), r"timed out while connecting to .*firewall"),
    ("timeout errno", connect_call_failed(errno.ETIMEDOUT), r"timed out while connecting"),
    ("reset", ConnectionResetError(errno.ECONNRESET, "reset"), r"connection to .* was reset"),
    (
        "several addresses",
        ExceptionGroup(
            "multiple connection attempts failed",
            [connect_call_failed(errno.EHOSTUNREACH, "::1"), connect_call_failed(113)],
        ),
        r"no route to",
    ),
    (
        "several addresses, asyncio",
        OSError(
            "Multiple exceptions: [Errno 113] Connect call failed ('::1', 7125, 0, 0), "
            "[Errno 113] Connect call failed ('127.0.0.1', 7125)"
        ),
        r"no route to",
    ),
]


@pytest.mark.parametrize(("cause", "exc", "wording"), CASES, ids=[c[0] for c in CASES])
def test_each_cause_has_its_sentence(cause: str, exc: BaseException, wording: str) -> None:
    for chain in (exc, anyio_failure(exc)):
        sentence = connect_problem(chain, "127.0.0.1:7125")
        assert "[Errno" not in sentence, sentence
        assert "Connect call failed" not in sentence, sentence
        assert re.search(wording, sentence), (cause, sentence)


def test_an_unknown_cause_still_names_the_place_and_what_to_do() -> None:
    sentence = connect_problem(OSError("something new"), "127.0.0.1:7125")
    assert "127.0.0.1:7125" in sentence
    assert "something new" in sentence
    assert "Retry later" in sentence


def raising(exc: BaseException) -> httpx.MockTransport:
    def handler(request: httpx.Request) -> httpx.Response:
        raise exc

    return httpx.MockTransport(handler)


@pytest.mark.parametrize(
    ("exc", "wording"),
    [(anyio_failure(exc), wording) for cause, exc, wording in CASES if "timeout" not in cause],
    ids=[c[0] for c in CASES if "timeout" not in c[0]],
)
async def test_http_requests_say_it(exc: BaseException, wording: str) -> None:
    async with httpx.AsyncClient(transport=raising(exc)) as http:
        client = MoonrakerClient(URL, http, name="p")
        with pytest.raises(PrinterUnreachable, match=wording) as error:
            await client.server_info()
    assert "[Errno" not in error.value.message


async def test_an_http_connect_timeout_says_it_and_is_a_timeout() -> None:
    timeout = httpx.ConnectTimeout("")
    timeout.__cause__ = TimeoutError()
    async with httpx.AsyncClient(transport=raising(timeout)) as http:
        client = MoonrakerClient(URL, http, name="p")
        with pytest.raises(PrinterTimeout, match=r"timed out while connecting to .*firewall"):
            await client.server_info()


async def test_a_real_tls_failure_on_loopback() -> None:
    """https:// to a plain HTTP port (a loopback TCP peer): a real TLS error."""

    async def plain(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        await reader.read(1024)
        writer.write(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
        await writer.drain()
        writer.close()

    server = await asyncio.start_server(plain, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    try:
        async with httpx.AsyncClient(trust_env=False) as http:
            client = MoonrakerClient(f"https://127.0.0.1:{port}", http, name="p")
            with pytest.raises(PrinterUnreachable, match=r"TLS .*handshake .* failed") as error:
                await client.server_info()
            assert "http://" in error.value.message
    finally:
        server.close()


# asyncio's create_connection (under picows) never raises a group; anyio's (under httpx) does.
SOCKET_CASES = [c for c in CASES if not isinstance(c[1], BaseExceptionGroup)]


@pytest.mark.parametrize(
    ("cause", "exc", "wording"), SOCKET_CASES, ids=[c[0] for c in SOCKET_CASES]
)
async def test_the_session_says_it_too(cause: str, exc: BaseException, wording: str) -> None:
    events: list[SessionEvent] = []

    async def connect(*_args: object, **_kwargs: object) -> None:
        raise exc

    async with httpx.AsyncClient() as http:
        client = MoonrakerClient(URL, http, name="p", on_event=events.append, connect=connect)
        client.session._backoff = Backoff(base=60.0)  # one attempt is enough here
        client.start()
        try:
            await wait_for(lambda: bool(drops(events)), what="the failed connect")
        finally:
            await client.close()
    why = drops(events)[0]
    assert re.search(wording, why), (cause, why)
    assert "[Errno" not in why


def drops(events: list[SessionEvent]) -> list[str]:
    return [
        e.detail for e in events if isinstance(e, ConnectionChanged) and e.connection == "offline"
    ]


def test_refused_is_told_apart_from_every_other_cause() -> None:
    """A refusal means the host is up (Moonraker restarting): the session retries quickly."""
    for cause, exc, _ in CASES:
        expected = cause == "refused"
        assert connection_refused(exc) is expected, cause
        assert connection_refused(anyio_failure(exc)) is expected, cause
    several = OSError(
        "Multiple exceptions: [Errno 111] Connect call failed ('::1', 7125, 0, 0), "
        "[Errno 111] Connect call failed ('127.0.0.1', 7125)"
    )
    assert connection_refused(several)
