"""What the printer page reads besides the live view: the printer's macros (from its real
Klipper configuration), the running print's objects, and whether its host serves Mainsail
or Fluidd."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import httpx
import pytest

from tests.api.conftest import StartEdge, add_printer
from tests.helpers import KyberCoreServer, objects_gcode, wait_until

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


def test_the_prints_objects_come_from_klipper_and_one_is_excluded_by_gcode(
    kybercore_server: KyberCoreServer,
) -> None:
    """A file whose slicer labelled its objects: the route lists them with their outlines
    and says which is printing; EXCLUDE_OBJECT through the G-code route excludes one."""
    with httpx.Client(base_url=kybercore_server.url, timeout=30) as api:
        idle = api.get("/api/printers/fleet-b/objects")
        assert idle.status_code == 200, idle.text
        assert idle.json()["available"] is True  # the virtual printers have [exclude_object]
        upload = api.post(
            "/api/printers/fleet-b/files",
            files={"file": ("objects.gcode", objects_gcode(60), "application/octet-stream")},
            data={"start": "true", "confirm": "true"},
        )
        assert upload.status_code == 201, upload.text
        assert upload.json()["started"] is True, upload.text
        try:

            def objects() -> dict[str, Any]:
                answer = api.get("/api/printers/fleet-b/objects")
                assert answer.status_code == 200, answer.text
                found: dict[str, Any] = answer.json()
                return found

            wait_until(lambda: objects()["current"] is not None, what="an object printing")
            found = objects()
            assert [o["name"] for o in found["objects"]] == ["PART_A", "PART_B"]
            assert found["objects"][1]["center"] == [105.0, 55.0]
            assert found["objects"][1]["polygon"][2] == [110.0, 60.0]
            assert found["excluded"] == []
            script = {"script": "EXCLUDE_OBJECT NAME=PART_B"}
            excluded = api.post("/api/printers/fleet-b/gcode", json=script)
            assert excluded.status_code == 200, excluded.text
            assert "Excluding object PART_B" in " ".join(excluded.json()["response"])
            assert objects()["excluded"] == ["PART_B"]
        finally:
            api.post("/api/printers/fleet-b/actions/cancel", json={})
            wait_until(
                lambda: api.get("/api/printers/fleet-b").json()["job"]["state"] == "cancelled",
                what="the print cancelled",
            )


def test_the_objects_of_an_unknown_printer_are_a_404(kybercore_server: KyberCoreServer) -> None:
    answer = httpx.get(f"{kybercore_server.url}/api/printers/nope/objects", timeout=30)
    assert answer.status_code == 404
    assert "nope" in answer.json()["error"]["message"]
