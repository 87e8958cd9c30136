"""Webcam snapshots: snapshot URLs resolved as Moonraker and the frontends mean them, and a
real virtual printer whose moonraker.conf lists webcams served by a loopback server."""

from __future__ import annotations

import io
import re
import time
from collections.abc import AsyncIterator, Callable, Iterator

import httpx
import pytest
from PIL import Image

from kybercore.fleet.webcams import MAX_SNAPSHOT, camera_candidates
from kybercore.moonraker.client import MoonrakerClient
from kybercore.notify.snapshot import take_snapshot
from kybercore.sim.stack import PrinterStack, free_port
from tests.notify.receiver import HANG, Receiver

# Listed first and disabled: it must be passed over.
WEBCAMS = """
[webcam switched_off]
enabled: False
stream_url: http://127.0.0.1:{port}/off-stream
snapshot_url: http://127.0.0.1:{port}/off.jpg

[webcam front]
service: mjpegstreamer
stream_url: http://127.0.0.1:{port}/stream
snapshot_url: http://127.0.0.1:{port}/front.jpg
"""


def image(kind: str = "JPEG") -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (64, 48), "orange").save(buffer, kind)
    return buffer.getvalue()


@pytest.mark.parametrize(
    ("printer_url", "snapshot_url", "expected"),
    [
        ("http://10.0.0.5:7125", "/webcam/?action=snapshot",
         "http://10.0.0.5:7125/webcam/?action=snapshot"),
        ("http://voron.local/", "/webcam/?action=snapshot",
         "http://voron.local/webcam/?action=snapshot"),
        ("http://10.0.0.5:7125/", "webcam/snap", "http://10.0.0.5:7125/webcam/snap"),
        ("https://farm.example/printers/p1", "/webcam2/snapshot",
         "https://farm.example/webcam2/snapshot"),
        ("http://10.0.0.5:7125", "http://10.0.0.9:8080/?action=snapshot",
         "http://10.0.0.9:8080/?action=snapshot"),
        ("http://10.0.0.5:7125", "https://cam.example/snap.jpg", "https://cam.example/snap.jpg"),
        ("https://voron.local", "//cam.local/snap", "https://cam.local/snap"),
        ("http://[fd00::5]:7125", "/snap", "http://[fd00::5]:7125/snap"),
        ("http://10.0.0.5:7125", "", None),
        ("http://10.0.0.5:7125", "   ", None),
        ("http://10.0.0.5:7125", "rtsp://10.0.0.5:8554/stream", None),
        ("http://10.0.0.5:7125", "file:///tmp/snap.jpg", None),
        ("http://10.0.0.5:7125", "webrtc://10.0.0.5/cam", None),
        ("not a url", "/webcam/?action=snapshot", None),
    ],
)  # fmt: skip
def test_resolve_snapshot_url(printer_url: str, snapshot_url: str, expected: str | None) -> None:
    assert (camera_candidates(printer_url, snapshot_url) or [None])[0] == expected


def test_a_relative_url_on_moonrakers_port_is_also_tried_on_the_hosts_default_port() -> None:
    # Moonraker's reading: a partial URL is on the frontend's web server (port 80).
    assert camera_candidates("http://10.0.0.5:7125", "/webcam/?action=snapshot") == [
        "http://10.0.0.5:7125/webcam/?action=snapshot",
        "http://10.0.0.5/webcam/?action=snapshot",
    ]
    assert camera_candidates("http://[fd00::5]:7125", "snap") == [
        "http://[fd00::5]:7125/snap",
        "http://[fd00::5]/snap",
    ]
    assert camera_candidates("http://voron.local", "/snap") == ["http://voron.local/snap"]
    assert camera_candidates("http://10.0.0.5:7125", "http://cam/snap") == ["http://cam/snap"]


@pytest.fixture(scope="module")
async def webcam() -> AsyncIterator[Receiver]:
    """The loopback server the printer's webcams point to."""
    server = Receiver()
    await server.start()
    yield server
    await server.stop()


@pytest.fixture(scope="module")
def webcam_printer(
    start_stack: Callable[..., PrinterStack], webcam: Receiver
) -> Iterator[PrinterStack]:
    """A virtual printer with two webcams of the test's in its moonraker.conf instead of
    the simulator's own: Moonraker is restarted on that config."""
    stack = start_stack("webcam", wait=False)
    stack.stop_moonraker()
    # These two instead of the simulator's own webcam: the test serves their pictures.
    conf = stack.data_dir / "config" / "moonraker.conf"
    own = re.sub(r"\[webcam kybercam\][^\[]*", "", conf.read_text())
    conf.write_text(own + WEBCAMS.format(port=webcam.port))
    stack.start_moonraker()
    stack.wait_ready()
    yield stack
    stack.stop()


@pytest.fixture
def client(webcam_printer: PrinterStack, http: httpx.AsyncClient) -> MoonrakerClient:
    return MoonrakerClient(webcam_printer.url, http, name="webcam")


async def test_the_first_enabled_webcams_jpeg_is_taken(
    client: MoonrakerClient, webcam_printer: PrinterStack, http: httpx.AsyncClient,
    webcam: Receiver,
) -> None:  # fmt: skip
    listed = await client.webcams_list()
    assert [(w["name"], w["enabled"]) for w in listed] == [
        ("switched_off", False), ("front", True),
    ]  # fmt: skip
    jpeg = image()
    webcam.serve("/front.jpg", jpeg)
    webcam.serve("/off.jpg", image())
    assert await take_snapshot(client, webcam_printer.url, http) == jpeg
    assert "/off.jpg" not in [r.path for r in webcam.requests]


@pytest.mark.parametrize(
    ("content", "content_type"),
    [
        (image("PNG"), "image/png"),
        (b"<html>Login required</html>", "text/html"),
        (b"\xff\xd8\xff" + bytes(MAX_SNAPSHOT), "image/jpeg"),  # a JPEG, but too big
    ],
    ids=["png", "html", "oversize"],
)
async def test_anything_but_a_small_jpeg_is_no_snapshot(
    client: MoonrakerClient, webcam_printer: PrinterStack, http: httpx.AsyncClient,
    webcam: Receiver, content: bytes, content_type: str,
) -> None:  # fmt: skip
    webcam.serve("/front.jpg", content, content_type)
    assert await take_snapshot(client, webcam_printer.url, http) is None


async def test_a_missing_or_hanging_webcam_is_no_snapshot_in_time(
    client: MoonrakerClient, webcam_printer: PrinterStack, http: httpx.AsyncClient,
    webcam: Receiver,
) -> None:  # fmt: skip
    webcam.unserve("/front.jpg")
    assert await take_snapshot(client, webcam_printer.url, http) is None
    webcam.serve("/front.jpg", HANG)
    started = time.monotonic()
    assert await take_snapshot(client, webcam_printer.url, http, timeout=0.5) is None
    assert time.monotonic() - started < 5.0  # the timeout holds, 10x slack


async def test_an_unreachable_moonraker_is_no_snapshot(http: httpx.AsyncClient) -> None:
    url = f"http://127.0.0.1:{free_port()}"
    assert await take_snapshot(MoonrakerClient(url, http, name="gone"), url, http) is None
