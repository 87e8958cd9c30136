"""Webcams through KyberCore: the list with proxy URLs, a JPEG snapshot and an MJPEG
stream relayed from the virtual printers' real webcams (Moonraker's [webcam] config)."""

from __future__ import annotations

import httpx
import pytest

from kybercore.sim.stack import PrinterStack
from tests.api.conftest import StartEdge, add_printer
from tests.helpers import KyberCoreServer, wait_until

pytestmark = pytest.mark.integration

JPEG = b"\xff\xd8\xff"


def test_the_list_gives_kybercores_own_urls(kybercore_server: KyberCoreServer) -> None:
    answer = httpx.get(f"{kybercore_server.url}/api/printers/fleet-a/webcams", timeout=30)
    assert answer.status_code == 200, answer.text
    [cam] = answer.json()
    assert cam["name"] == "kybercam"
    assert cam["snapshot_url"] == "/api/printers/fleet-a/webcams/kybercam/snapshot"
    assert cam["stream_url"] == "/api/printers/fleet-a/webcams/kybercam/stream"
    assert cam["rotation"] == 0


def test_a_snapshot_is_a_jpeg_never_cached(kybercore_server: KyberCoreServer) -> None:
    url = f"{kybercore_server.url}/api/printers/fleet-a/webcams/kybercam/snapshot"
    answer = httpx.get(url, timeout=30)
    assert answer.status_code == 200, answer.text
    assert answer.headers["content-type"] == "image/jpeg"
    assert answer.headers["cache-control"] == "no-store"
    assert answer.content.startswith(JPEG)


def test_the_stream_relays_mjpeg_parts(kybercore_server: KyberCoreServer) -> None:
    url = f"{kybercore_server.url}/api/printers/fleet-b/webcams/kybercam/stream"
    with httpx.stream("GET", url, timeout=30) as answer:
        assert answer.status_code == 200
        assert answer.headers["content-type"].startswith("multipart/x-mixed-replace")
        received = b""
        for chunk in answer.iter_raw():
            received += chunk
            if received.count(JPEG) >= 2:
                break
    assert received.count(JPEG) >= 2


def test_an_unknown_webcam_is_a_404_that_says_where_to_look(
    kybercore_server: KyberCoreServer,
) -> None:
    url = f"{kybercore_server.url}/api/printers/fleet-a/webcams/nope/snapshot"
    answer = httpx.get(url, timeout=30)
    assert answer.status_code == 404
    assert "/api/printers/fleet-a/webcams" in answer.json()["error"]["message"]


def test_a_dead_camera_and_an_offline_printer_are_clear_errors(
    edge_server: StartEdge, own_printer: PrinterStack
) -> None:
    server, _ = edge_server()
    add_printer(server, "cam", own_printer.url)
    server.wait_online(1, timeout=60)
    own_printer.stop_webcam()
    snap = httpx.get(f"{server.url}/api/printers/cam/webcams/kybercam/snapshot", timeout=30)
    assert snap.status_code == 503, snap.text
    assert "gave no JPEG snapshot" in snap.json()["error"]["message"]
    own_printer.stop_moonraker()
    # Once KyberCore knows the printer is gone (the webcam list is reused for a few seconds).
    wait_until(lambda: connection(server.url, "cam") != "online", what="cam offline")
    listed = httpx.get(f"{server.url}/api/printers/cam/webcams", timeout=30)
    assert listed.status_code in (409, 503), listed.text


def connection(server_url: str, printer_id: str) -> object:
    return httpx.get(f"{server_url}/api/printers/{printer_id}", timeout=30).json()["connection"]


def test_webcams_need_a_login_when_tokens_are_on(edge_server: StartEdge) -> None:
    server, _ = edge_server(tokens=True)
    answer = httpx.get(f"{server.url}/api/printers/any/webcams/cam/snapshot", timeout=30)
    assert answer.status_code == 401
