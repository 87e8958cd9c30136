"""Small `kybercore serve` processes for the tests of the HTTP edge: no printers, so they
start in about a second and each test can have its own (open, or with tokens)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest

from kybercore.api.auth import TokenStore, tokens_path_for
from kybercore.registry.store import write_printers
from kybercore.sim.stack import free_port
from tests.helpers import KyberCoreServer

PROXY_NAME = "printers.example"
"""The name a reverse proxy forwards as Host; every edge server allows it."""

StartEdge = Callable[..., tuple[KyberCoreServer, str]]


@pytest.fixture
def edge_server(tmp_path: Path) -> Iterator[StartEdge]:
    """Start an empty-fleet server: (server, admin token). ``tokens=True`` creates the admin
    token before the start, so that it runs in tokens mode; otherwise it is open and the
    token is ""."""
    started: list[KyberCoreServer] = []

    def start(*, tokens: bool = False, name: str = "edge") -> tuple[KyberCoreServer, str]:
        folder = tmp_path / f"{name}-{len(started)}"
        folder.mkdir()
        printers = folder / "printers.json"
        write_printers(printers, [])
        token = ""
        if tokens:
            _, token = TokenStore(tokens_path_for(printers)).create("root", "admin")
        server = KyberCoreServer(printers, free_port(), "--allowed-host", PROXY_NAME)
        started.append(server)
        server.start()
        return server, token

    yield start
    for server in started:
        server.stop()


def add_printer(server: KyberCoreServer, printer_id: str, url: str) -> None:
    """Add a printer through the API (without the connection test), named after its id."""
    added = httpx.post(
        f"{server.url}/api/printers",
        json={"id": printer_id, "name": printer_id.title(), "moonraker_url": url},
        timeout=30,
    )
    assert added.status_code == 201, added.text
