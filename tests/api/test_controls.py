"""What the printer page reads besides the live view: the printer's macros (from its real
Klipper configuration) and whether its host serves Mainsail or Fluidd."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import httpx
import pytest

from tests.api.conftest import StartEdge, add_printer
from tests.helpers import KyberCoreServer

pytestmark = pytest.mark.integration

# Mainsail is served on port 80 of the printer's host, away from Moonraker's port: a
# loopback address of its own lets the test have a port 80 nothing else uses.
FAKE_HOST = "127.0.0.3"


class _FakeMainsail(BaseHTTPRequestHandler):
    """Fake: the index page a Mainsail install serves (its title is what is probed)."""

    def do_GET(self) -> None:
        body = b"<!doctype html><html><head><title>Mainsail</title></head><body></body></html>"
        self.send_response(200)
        self.send_header("Content-Type", "text/html")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, format: str, *args: object) -> None:
        """Quiet: the test reads the answers, not a log."""


@pytest.fixture
def fake_mainsail() -> Iterator[str]:
    server = ThreadingHTTPServer((FAKE_HOST, 80), _FakeMainsail)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://{FAKE_HOST}/"
    server.shutdown()
    server.server_close()


def test_macros_come_from_klippers_config_without_the_helpers(
    kybercore_server: KyberCoreServer,
) -> None:
    answer = httpx.get(f"{kybercore_server.url}/api/printers/fleet-a/macros", timeout=30)
    assert answer.status_code == 200, answer.text
    by_name = {m["name"]: m["description"] for m in answer.json()}
    assert by_name["PARK"] == "Move the toolhead to the back corner, clear of the part"
    assert "CANCEL_PRINT" in by_name
    assert not [name for name in by_name if name.startswith("_")]


def test_macros_of_an_unknown_printer_are_a_404(kybercore_server: KyberCoreServer) -> None:
    answer = httpx.get(f"{kybercore_server.url}/api/printers/nope/macros", timeout=30)
    assert answer.status_code == 404
    assert "nope" in answer.json()["error"]["message"]


def test_a_host_without_a_web_interface_gets_no_link(kybercore_server: KyberCoreServer) -> None:
    answer = httpx.get(f"{kybercore_server.url}/api/printers/fleet-a/web_ui", timeout=30)
    assert answer.status_code == 200, answer.text
    assert answer.json() == {"kind": None, "url": None}


def test_a_host_serving_mainsail_gets_its_link(edge_server: StartEdge, fake_mainsail: str) -> None:
    server, _ = edge_server()
    add_printer(server, "voron", f"http://{FAKE_HOST}:7125")
    answer = httpx.get(f"{server.url}/api/printers/voron/web_ui", timeout=30)
    assert answer.status_code == 200, answer.text
    assert answer.json() == {"kind": "mainsail", "url": fake_mainsail}
