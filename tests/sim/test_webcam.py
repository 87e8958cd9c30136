"""The virtual printers' webcam: found through the real Moonraker, drawing the real print."""

from __future__ import annotations

import contextlib
import io
import math
import os
import signal
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from urllib.parse import urlsplit

import httpx
import pytest
from PIL import Image

from kybercore.moonraker.client import MoonrakerClient
from kybercore.sim.stack import PrinterStack
from kybercore.sim.webcam import STATUS_MAX_AGE, STATUS_WAIT
from kybercore.sim.webcam_frame import PART_COLOURS, CameraStatus, status_from_query
from tests.helpers import travel_gcode, wait_for

pytestmark = pytest.mark.integration

BED_PX = 380  # the drawing's bed area: a 220 mm square bed fills it
RMAX_PX = 0.3 * BED_PX  # the part's radius at 100 %


@pytest.fixture(scope="module")
def cam_printer(start_stack: Callable[..., PrinterStack]) -> Iterator[PrinterStack]:
    """A printer of this module's own: these tests print on it."""
    stack = start_stack("cam", size=(220.0, 220.0, 250.0))
    yield stack
    stack.stop()


def _jpeg(content: bytes) -> Image.Image:
    image = Image.open(io.BytesIO(content))
    image.load()
    assert image.format == "JPEG"
    return image


def _part_share(image: Image.Image, colour: tuple[int, int, int]) -> float:
    """How much of a full-size part the bed area shows in ``colour`` (0 to about 1)."""
    pixels = image.convert("RGB").crop((20, 60, 400, 440)).tobytes()
    red, green, blue = colour
    near = sum(
        1
        for i in range(0, len(pixels), 3)
        if abs(pixels[i] - red) + abs(pixels[i + 1] - green) + abs(pixels[i + 2] - blue) < 60
    )
    return near / (math.pi * RMAX_PX**2)


def _clients(pid: int, port: int) -> int:
    """Connections process ``pid`` holds open on its listening ``port`` (its clients)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        with contextlib.suppress(OSError):  # closed while we looked
            inodes.add(os.readlink(fd).removeprefix("socket:[").removesuffix("]"))
    count = 0
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        fields = line.split()
        local_port, state, inode = int(fields[1].split(":")[1], 16), fields[3], fields[9]
        count += local_port == port and state != "0A" and inode in inodes  # 0A: listening
    return count


async def test_moonraker_lists_the_webcam_and_its_snapshot_is_a_jpeg(
    cam_printer: PrinterStack, http: httpx.AsyncClient
) -> None:
    answer = await http.get(f"{cam_printer.url}/server/webcams/list")
    (cam,) = answer.json()["result"]["webcams"]
    assert cam["name"] == "kybercam"
    assert cam["snapshot_url"] == f"{cam_printer.webcam_url}/snapshot"
    assert cam["stream_url"] == f"{cam_printer.webcam_url}/stream"
    for url in (cam["snapshot_url"], cam["stream_url"]):
        parts = urlsplit(url)
        assert (parts.scheme, parts.hostname, parts.port) == (
            "http", "127.0.0.1", cam_printer.webcam_port,
        )  # fmt: skip

    snapshot = await http.get(cam["snapshot_url"])
    assert snapshot.status_code == 200
    assert snapshot.headers["content-type"] == "image/jpeg"
    assert snapshot.headers["cache-control"] == "no-store"
    assert _jpeg(snapshot.content).size == (640, 480)
    # Moonraker itself reaches it, as it would a real camera.
    tested = await http.post(f"{cam_printer.url}/server/webcams/test", params={"name": "kybercam"})
    assert tested.json()["result"]["snapshot_reachable"] is True
    missing = await http.get(f"{cam_printer.webcam_url}/nothing-here")
    assert missing.status_code == 404


async def test_the_drawing_follows_the_print(
    cam_printer: PrinterStack, http: httpx.AsyncClient
) -> None:
    orange, red = PART_COLOURS["printing"], PART_COLOURS["cancelled"]
    client = MoonrakerClient(cam_printer.url, http, name="cam")
    snapshot_url = f"{cam_printer.webcam_url}/snapshot"

    async def drawn(colour: tuple[int, int, int]) -> float:
        return _part_share(_jpeg((await http.get(snapshot_url)).content), colour)

    async def progress() -> float:
        status = await client.objects_query({"virtual_sdcard": ["progress"]})
        return float(status["virtual_sdcard"]["progress"])  # type: ignore[arg-type]

    async def printed(share: float) -> bool:
        return await progress() >= share

    async def cancelled_part() -> bool:
        return await drawn(red) > 0.05

    assert await drawn(orange) < 0.01  # an empty bed

    # Travel moves only: about 70 s of printing without heating.
    await client.upload("webcam_travel.gcode", travel_gcode(moves=40, feedrate=1800))
    await client.print_start("webcam_travel.gcode")
    shares: list[float] = []
    for target in (0.1, 0.35):
        await wait_for(lambda t=target: printed(t), timeout=60, what=f"{target:.0%} printed")
        share = await drawn(orange)
        # The part's area is the progress Moonraker reports (drawn from a status at most a
        # second or two old: the file moves about 1.5 % a second).
        assert abs(share - await progress()) < 0.1, (share, await progress())
        shares.append(share)
    assert shares[1] > shares[0] + 0.1

    await client.print_cancel()
    await wait_for(cancelled_part, timeout=10, what="the part drawn as cancelled")
    assert await drawn(orange) < 0.01


def test_the_stream_sends_frames_until_the_client_leaves(cam_printer: PrinterStack) -> None:
    pid, port = cam_printer.pids["webcam"], cam_printer.webcam_port
    with httpx.Client(timeout=10, trust_env=False) as http:
        with http.stream("GET", f"{cam_printer.webcam_url}/stream") as stream:
            assert stream.headers["content-type"] == "multipart/x-mixed-replace; boundary=frame"
            buffer = b""
            chunks = stream.iter_bytes()
            while buffer.count(b"--frame\r\n") < 3:  # two whole frames and a third begun
                buffer += next(chunks)
            assert _clients(pid, port) == 1
        frames = buffer.split(b"--frame\r\n")[1:3]
        for part in frames:
            head, _, body = part.partition(b"\r\n\r\n")
            assert b"Content-Type: image/jpeg" in head
            length = int(head.split(b"Content-Length: ")[1].split(b"\r\n")[0])
            assert _jpeg(body[:length]).size == (640, 480)
            assert body[length:] == b"\r\n"
    # The client left: the server notices and closes its side of the connection.
    deadline = time.monotonic() + 10
    while _clients(pid, port):
        assert time.monotonic() < deadline, "the stream's connection is still open"
        time.sleep(0.05)  # poll: wait for the server to close, deadline above


def test_a_frozen_moonraker_does_not_freeze_the_picture(own_printer: PrinterStack) -> None:
    url = f"{own_printer.webcam_url}/snapshot"
    with httpx.Client(timeout=30, trust_env=False) as http:
        assert http.get(url).status_code == 200
        os.kill(own_printer.pids["moonraker"], signal.SIGSTOP)
        try:
            # Ask for frames until the status is stale twice over: each must still come at
            # once, drawn with the last status after waiting STATUS_WAIT for a new one
            # (without that wait's limit, a frame would wait for Moonraker's 10 s timeout).
            watched = time.monotonic()
            while time.monotonic() - watched < 2 * STATUS_MAX_AGE + STATUS_WAIT:
                started = time.monotonic()
                assert _jpeg(http.get(url).content).size == (640, 480)
                assert time.monotonic() - started < 5 * STATUS_WAIT
        finally:
            os.kill(own_printer.pids["moonraker"], signal.SIGCONT)


def test_the_webcam_stops_with_its_printer_even_while_streaming(
    own_printer: PrinterStack,
) -> None:
    pid = own_printer.pids["webcam"]
    with (
        httpx.Client(timeout=10, trust_env=False) as http,
        http.stream("GET", f"{own_printer.webcam_url}/stream") as stream,
    ):
        next(stream.iter_bytes())
        own_printer.stop()
    assert "webcam" not in own_printer.pids
    assert not Path(f"/proc/{pid}").exists(), f"webcam process {pid} left behind"
    # It ended on SIGTERM by itself (not killed after the grace period), stream and all.
    assert "webcam stopped" in (own_printer.data_dir / "logs" / "webcam.out").read_text()


def test_the_status_says_what_the_printer_does() -> None:
    printing = {
        "webhooks": {"state": "ready", "state_message": "Printer is ready"},
        "print_stats": {
            "state": "printing",
            "filename": "cube.gcode",
            "info": {"current_layer": None, "total_layer": None},
        },
        "virtual_sdcard": {"progress": 0.25},
        "display_status": {"progress": 0.2},
        "toolhead": {
            "position": [10.0, 20.0, 1.0, 0.0],
            "axis_minimum": [0.0, 0.0, 0.0, 0.0],
            "axis_maximum": [300.0, 250.0, 300.0, 0.0],
        },
    }
    meta = {"layer_height": 0.2, "first_layer_height": 0.2, "object_height": 20.0}
    assert status_from_query(printing, meta) == CameraStatus(
        state="printing",
        progress=0.25,
        filename="cube.gcode",
        layer=5,  # z 1.0: 0.2 + 4 × 0.2
        total_layers=100,
        nozzle=(10.0, 20.0),
        bed=(0.0, 0.0, 300.0, 250.0),
    )
    # The slicer's SET_PRINT_STATS_INFO wins over the estimate.
    printing["print_stats"]["info"] = {"current_layer": 7, "total_layer": 90}
    status = status_from_query(printing, meta)
    assert (status.layer, status.total_layers) == (7, 90)

    shutdown = {
        "webhooks": {"state": "shutdown", "state_message": "MCU 'mcu' shutdown: Timer too close\n"}
    }
    status = status_from_query(shutdown, {})
    assert (status.state, status.message) == ("shutdown", "MCU 'mcu' shutdown: Timer too close")
    assert status_from_query({"print_stats": {"state": "complete"}}, {}).progress == 1.0

    # A cancelled print: Klipper resets its file position, the part stays on the bed.
    cancelled = {
        "print_stats": {"state": "cancelled", "filename": "cube.gcode", "filament_used": 300.0},
        "virtual_sdcard": {"progress": 0.0},
    }
    seen = CameraStatus("printing", progress=0.4, filename="cube.gcode")
    assert status_from_query(cancelled, {}, seen).progress == 0.4
    # Not seen printing (nobody was watching): the share of the filament used.
    assert status_from_query(cancelled, {"filament_total": 1200.0}).progress == 0.25
