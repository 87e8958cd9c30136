"""The webcam proxy's live streams against a real virtual printer's camera: a printer has
at most ``max_streams`` open, and a stream closed, even one never read (a browser that left
before the first byte), frees its place and the camera's connection."""

from __future__ import annotations

import httpx
import pytest

from kybercore.errors import ActionRejected
from kybercore.fleet.webcams import Webcam, WebcamProxy
from kybercore.sim.stack import PrinterStack

pytestmark = pytest.mark.integration


def camera_of(printer: PrinterStack) -> Webcam:
    return Webcam(
        name="kybercam", enabled=True, snapshot_urls=[],
        stream_urls=[f"{printer.webcam_url}/stream"], flip_horizontal=False,
        flip_vertical=False, rotation=0, aspect_ratio="4:3",
    )  # fmt: skip


async def test_a_stream_closed_unread_frees_its_place(fleet_stacks: list[PrinterStack]) -> None:
    cam = camera_of(fleet_stacks[0])
    async with httpx.AsyncClient() as http:
        proxy = WebcamProxy(http, max_streams=2)
        first = await proxy.stream(cam, "p1")
        second = await proxy.stream(cam, "p1")
        assert first.content_type.startswith("multipart/x-mixed-replace")
        with pytest.raises(ActionRejected, match="2 webcam streams are open already"):
            await proxy.stream(cam, "p1")
        other = await proxy.stream(cam, "p2")  # the limit is per printer
        await first.aclose()  # never read
        await first.aclose()  # closing twice is harmless, and frees one place only
        third = await proxy.stream(cam, "p1")
        with pytest.raises(ActionRejected):
            await proxy.stream(cam, "p1")
        received = b""
        async for chunk in third:
            received += chunk
            if b"\xff\xd8\xff" in received:
                break
        assert b"\xff\xd8\xff" in received
        for stream in (second, third, other):
            await stream.aclose()
        again = await proxy.stream(cam, "p1")  # every place free again
        await again.aclose()
