"""The HTTP edge refuses what a web page or an anonymous client could abuse, before reading
it: a Host that is not ours (DNS rebinding), an unauthenticated write, a body over its
route's limit however it is sent, header bytes that are not UTF-8."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import websockets

from kybercore.api.auth import COOKIE
from tests.api.conftest import PROXY_NAME, StartEdge
from tests.hardening.faults import RssSampler
from tests.helpers import KyberCoreServer

pytestmark = pytest.mark.integration

SAMPLES = Path(__file__).resolve().parents[2] / "src/kybercore/sim/samples"
NEW_PRINTER = {"name": "Rebound", "moonraker_url": "http://127.0.0.1:9"}
MiB = 2**20


def _as(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"} if token else {}


def _named(server: KyberCoreServer, name: str) -> dict[str, str]:
    """Headers of a browser page at http://NAME:PORT calling its own origin: what a page
    sends after DNS rebinding (NAME now resolves to this server) or through a proxy."""
    netloc = f"{name}:{server.port}"
    return {"Host": netloc, "Origin": f"http://{netloc}"}


async def _ws_refused(server: KyberCoreServer, name: str, headers: dict[str, str]) -> bool:
    """Whether /ws refuses a handshake made to http://NAME:PORT from that origin (the TCP
    connection goes to this server, as after a rebinding)."""
    netloc = f"{name}:{server.port}"
    try:
        async with websockets.connect(
            f"ws://{netloc}/ws",
            host="127.0.0.1",
            port=server.port,
            origin=f"http://{netloc}",  # type: ignore[arg-type]
            additional_headers=headers,
        ) as ws:
            assert await ws.recv()  # the snapshot: the socket really works
            return False
    except websockets.InvalidStatus:
        return True


@pytest.mark.parametrize("tokens", [False, True], ids=["open", "tokens"])
async def test_a_rebound_name_is_refused_and_a_proxy_name_is_served(
    edge_server: StartEdge, tokens: bool
) -> None:
    server, token = edge_server(tokens=tokens)
    auth = _as(token)
    with httpx.Client(base_url=server.url, headers=auth) as client:
        rebound = client.post(
            "/api/printers", json=NEW_PRINTER, headers=_named(server, "evil.example")
        )
        assert rebound.status_code == 421, rebound.text
        assert rebound.json()["error"]["code"] == "unknown_host"
        assert "--allowed-host evil.example" in rebound.json()["error"]["message"]
        assert client.get("/api/session", headers={"Host": "evil.example"}).status_code == 421
        assert client.get("/api/printers").json() == []  # nothing was added

        proxied = client.post("/api/printers", json=NEW_PRINTER, headers=_named(server, PROXY_NAME))
        assert proxied.status_code == 201, proxied.text
        # Any port: behind a proxy the Host names the proxy's port, not ours.
        assert client.get("/api/printers", headers={"Host": f"{PROXY_NAME}:443"}).is_success
        assert client.get("/api/printers", headers={"Host": "localhost"}).is_success

    assert await _ws_refused(server, "evil.example", auth)
    assert not await _ws_refused(server, PROXY_NAME, auth)
    assert not await _ws_refused(server, "127.0.0.1", auth)


def _chunks(total: int, sent: list[int], chunk: int = 64 * 1024) -> Iterator[bytes]:
    """A chunked body of ``total`` bytes made on the fly; ``sent[0]`` counts what left."""
    block = b"x" * chunk
    while sent[0] < total:
        sent[0] += chunk
        yield block


def test_an_anonymous_chunked_body_is_refused_before_it_is_read(edge_server: StartEdge) -> None:
    server, _ = edge_server(tokens=True)
    total = 100 * 10**6
    sent = [0]
    with RssSampler(server.pid) as memory, httpx.Client(timeout=30) as client:
        try:
            answer: httpx.Response | None = client.post(
                f"{server.url}/api/printers",
                content=_chunks(total, sent),
                headers={"Content-Type": "application/json"},
            )
        except httpx.TransportError:
            answer = None  # closed mid-upload: the refusal may be lost with the socket
    growth = memory.peak - memory.before
    outcome = answer.status_code if answer is not None else "the connection closed"
    print(
        f"\n100 MB chunked, no token: {outcome}; server RSS +{growth / MiB:.1f} MiB; the "
        f"client could send {sent[0] / MiB:.1f} MiB before the server closed"
    )
    if answer is not None:
        assert answer.status_code == 401, answer.text
        assert answer.json()["error"]["code"] == "unauthorized"
    # Before the fix the whole body was read first (RSS grew by its size, ~100 MB and more).
    assert growth < 50 * MiB
    # The server answered and closed at once: what left the client is what the sockets'
    # buffers took in the meantime (0.1 MiB measured), nowhere near the 100 MB.
    assert sent[0] < 16 * MiB


def test_a_body_over_its_route_limit_is_refused_however_it_is_sent(
    edge_server: StartEdge,
) -> None:
    server, _ = edge_server()
    with httpx.Client(base_url=server.url, timeout=30) as client:
        for path in ("/api/printers", "/api/session"):
            sent = [0]
            answer = client.post(
                path, content=_chunks(2 * MiB, sent), headers={"Content-Type": "application/json"}
            )
            assert answer.status_code == 413, (path, answer.text[:300])
            assert answer.json()["error"]["code"] == "too_large"
            assert "1 MiB" in answer.json()["error"]["message"]
            declared = client.post(path, content=b"{" + b" " * (2 * MiB) + b"}")
            assert declared.status_code == 413, (path, declared.text[:300])
        # The upload route keeps the upload limit: 2 MiB pass the edge (the printer is unknown).
        upload = client.post(
            "/api/printers/nope/files", files={"file": ("a.gcode", b"G28\n" * (MiB // 2))}
        )
        assert upload.status_code == 404, upload.text


def test_header_bytes_that_are_not_utf8_are_a_clean_4xx(edge_server: StartEdge) -> None:
    server, _ = edge_server(tokens=True)
    with httpx.Client(base_url=server.url) as client:
        for headers in (
            {"Authorization": b"Bearer caf\xe9"},
            {"Cookie": COOKIE.encode() + b"=caf\xe9"},
            {"X-Anything": b"\xe9"},
        ):
            answer = client.get("/api/printers", headers=headers)
            assert answer.status_code == 401, (headers, answer.status_code, answer.text)
            write = client.post("/api/printers", json=NEW_PRINTER, headers=headers)
            assert write.status_code == 401, (headers, write.status_code, write.text)


def test_thumbnails_are_cached_by_the_browser_only(kybercore_server: KyberCoreServer) -> None:
    """A thumbnail may be behind a token: no shared cache (a proxy) may keep it."""
    sample = SAMPLES / "calibration_cube_10mm_petg.gcode"
    name = "edge-thumbnail.gcode"
    files = f"{kybercore_server.url}/api/printers/fleet-c/files"
    with httpx.Client(timeout=30) as client:
        assert client.post(files, files={"file": (name, sample.read_bytes())}).status_code == 201
        try:
            meta = client.get(f"{files}/metadata", params={"filename": name}).json()
            path = meta["thumbnails"][0]["relative_path"]
            answer = client.get(f"{files}/thumbnail", params={"path": path})
            assert answer.status_code == 200
            assert answer.headers["cache-control"] == "private, max-age=300"
        finally:
            client.delete(files, params={"path": name})
