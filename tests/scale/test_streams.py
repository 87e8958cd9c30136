"""A webcam's stream relayed from a printer's owner to a front over a real nats-server: the
bytes cross whole and in order, and the relay stops (closing the camera's connection) when
the browser leaves, when it stops reading, when the owner loses the printer or stops, and a
lost chunk ends the stream. The camera is a fake: the tests choose when it sends."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from typing import Any

import pytest
from nats.aio.client import Client

from kybercore.errors import ActionRejected, InvalidInput
from kybercore.scale.broker import LocalServer, connect
from kybercore.scale.commands import CommandRunner
from kybercore.scale.streams import SEQ_HEADER, RelayedStream, StreamRelay, open_stream
from kybercore.scale.wire import command_subject
from tests.helpers import subscribed, wait_for

PRINTER = "p1"
BOUND = 30.0
"""Seconds any of these waits may take: each is a few broker round trips."""


class FakeCamera:
    """Fake: a camera's stream whose chunks the test hands over one by one."""

    content_type = "multipart/x-mixed-replace; boundary=frame"

    def __init__(self) -> None:
        self.chunks: asyncio.Queue[bytes | None] = asyncio.Queue()
        self.taken = 0
        """Bytes the relay has read from the camera."""
        self.closed = False

    def __aiter__(self) -> AsyncIterator[bytes]:
        return self._read()

    async def _read(self) -> AsyncIterator[bytes]:
        while (chunk := await self.chunks.get()) is not None:
            self.taken += len(chunk)
            yield chunk

    async def aclose(self) -> None:
        self.closed = True


@dataclass
class FakeService:
    """Fake: the FleetService's camera_stream, one fake camera per stream opened."""

    opened: list[FakeCamera] = field(default_factory=list)
    refuse: Exception | None = None

    async def camera_stream(self, printer_id: str, name: str) -> FakeCamera:
        if self.refuse is not None:
            raise self.refuse
        camera = FakeCamera()
        self.opened.append(camera)
        return camera


@dataclass
class Owner:
    service: FakeService
    relay: StreamRelay
    epoch: int | None = 1


@pytest.fixture
async def nc(nats_server: LocalServer) -> AsyncIterator[Client]:
    client = await connect(nats_server.url, "front")
    yield client
    await client.close()


async def start_owner(nats_server: LocalServer, **relay: Any) -> AsyncIterator[Owner]:
    owner_nc = await connect(nats_server.url, "owner")
    owner = Owner(FakeService(), StreamRelay(owner_nc, lambda pid: owner.epoch, **relay))
    runner = CommandRunner(
        owner.service,
        lambda pid: owner.epoch,
        streams=owner.relay,  # type: ignore[arg-type]
    )
    await owner_nc.subscribe(command_subject(PRINTER), cb=runner.on_message)
    await subscribed(owner_nc)  # before the front, on its own connection, asks
    yield owner
    await runner.stop()
    await owner_nc.close()


@pytest.fixture
async def owner(nats_server: LocalServer) -> AsyncIterator[Owner]:
    async for started in start_owner(nats_server):
        yield started


@pytest.fixture
async def small_window_owner(nats_server: LocalServer) -> AsyncIterator[Owner]:
    # A 1 kB window: the front's acknowledgements must keep the bytes going.
    async for started in start_owner(nats_server, window=1024):
        yield started


@pytest.fixture
async def impatient_owner(nats_server: LocalServer) -> AsyncIterator[Owner]:
    # A 1 kB window and 1 s without news before it gives up.
    async for started in start_owner(nats_server, window=1024, stall=1.0):
        yield started


async def flowing(
    nc: Client, owner: Owner
) -> tuple[RelayedStream, FakeCamera, AsyncIterator[bytes]]:
    """A stream opened through the front, its camera, and its bytes, the first chunk read."""
    stream = await open_stream(nc, PRINTER, "cam", epoch=1)
    [camera] = owner.service.opened
    camera.chunks.put_nowait(b"--frame\r\n")
    chunks = aiter(stream)
    assert await read(chunks, 1) == b"--frame\r\n"
    return stream, camera, chunks


async def read(stream: AsyncIterator[bytes], size: int) -> bytes:
    received = b""
    async with asyncio.timeout(BOUND):
        async for chunk in stream:
            received += chunk
            if len(received) >= size:
                break
    return received


async def test_the_bytes_cross_whole_and_in_order_and_the_camera_ends_the_stream(
    nc: Client, small_window_owner: Owner
) -> None:
    stream = await open_stream(nc, PRINTER, "cam", epoch=1)
    assert stream.content_type == FakeCamera.content_type
    [camera] = small_window_owner.service.opened
    # Past the window many times over, and one chunk larger than half a NATS message
    # (1 MB here), so it crosses in parts.
    sent = [bytes([i]) * 300 for i in range(40)] + [b"\xff" * (700 * 1024)]
    for chunk in sent:
        camera.chunks.put_nowait(chunk)
    camera.chunks.put_nowait(None)
    received = b""
    async with asyncio.timeout(BOUND):
        async for chunk in stream:
            received += chunk
    assert received == b"".join(sent)
    assert stream.ended == "the camera ended its stream"
    assert camera.closed
    await wait_for(lambda: small_window_owner.relay.relaying == 0, BOUND, "the relay ends")
    await stream.aclose()


async def test_a_browser_that_leaves_stops_the_relay_and_frees_the_camera(
    nc: Client, owner: Owner
) -> None:
    stream, camera, _ = await flowing(nc, owner)
    await stream.aclose()  # the browser left: the front unsubscribes

    def camera_sends_and_relay_stopped() -> bool:
        # The camera goes on sending; the first chunk the broker has nobody to give to is
        # answered "no responders" (the window, 4 MB, is far from full).
        camera.chunks.put_nowait(b"--frame\r\n")
        return camera.closed and owner.relay.relaying == 0

    await wait_for(camera_sends_and_relay_stopped, BOUND, "the relay stops")
    assert camera.taken < 1024 * 1024


async def test_a_front_that_never_reads_stops_the_relay_after_one_window(
    nc: Client, impatient_owner: Owner
) -> None:
    stream = await open_stream(nc, PRINTER, "cam", epoch=1)  # never read
    [camera] = impatient_owner.service.opened
    for _ in range(100):
        camera.chunks.put_nowait(b"x" * 100)
    await wait_for(lambda: camera.closed, BOUND, "the relay gives up on a front not reading")
    # It read one window (1 kB) from the camera, the chunk that overfilled it and the one
    # that then waited for room in vain; never the rest.
    assert 1024 <= camera.taken <= 1024 + 2 * 100
    await stream.aclose()


async def test_the_stream_ends_saying_why_when_the_owner_loses_the_printer(
    nc: Client, owner: Owner
) -> None:
    stream, camera, chunks = await flowing(nc, owner)
    owner.epoch = None  # its lease is gone: it may no longer publish for the printer
    camera.chunks.put_nowait(b"second")
    assert await read(chunks, 1) == b""
    assert stream.ended == "the printer moved to another worker"
    assert camera.closed


async def test_a_worker_that_stops_ends_its_streams(nc: Client, owner: Owner) -> None:
    stream = await open_stream(nc, PRINTER, "cam", epoch=1)
    [camera] = owner.service.opened
    await owner.relay.stop()
    assert await read(aiter(stream), 1) == b""
    assert stream.ended == "the printer's worker stopped"
    assert camera.closed


async def test_a_lost_chunk_ends_the_stream(nc: Client, owner: Owner) -> None:
    stream, _, chunks = await flowing(nc, owner)
    # Chunk 1 never arrives; chunk 2 does (as after a slow consumer's drop).
    await nc.publish(stream._sub.subject, b"2", headers={SEQ_HEADER: "2"})
    assert await read(chunks, 1) == b""
    assert stream.ended == "a chunk was lost on the way"


async def test_the_owners_refusal_is_the_fronts_error_and_no_stream_is_left_open(
    nc: Client, owner: Owner
) -> None:
    owner.service.refuse = ActionRejected("p1: 4 webcam streams are open already", code="x")
    with pytest.raises(ActionRejected, match="4 webcam streams are open already"):
        await open_stream(nc, PRINTER, "cam", epoch=1)
    assert owner.relay.relaying == 0
    # The inbox is unsubscribed: nothing of the refused stream stays on the front.
    assert all(not sub.subject.startswith("_INBOX.") for sub in nc._subs.values())


async def test_a_stream_goes_only_to_an_inbox(owner: Owner) -> None:
    with pytest.raises(InvalidInput, match="reply inbox"):
        await owner.relay.open(owner.service, PRINTER, {"name": "cam", "to": "kc.cmd.p2"})  # type: ignore[arg-type]
    assert owner.service.opened == []


async def test_the_fronts_broker_connection_closing_ends_the_stream(
    nc: Client, owner: Owner
) -> None:
    stream, camera, chunks = await flowing(nc, owner)
    await nc.close()
    assert await read(chunks, 1) == b""
    assert stream.ended.startswith("the broker connection broke")

    def camera_sends_and_relay_stopped() -> bool:
        camera.chunks.put_nowait(b"--frame\r\n")  # the owner hears "no responders"
        return camera.closed and owner.relay.relaying == 0

    await wait_for(camera_sends_and_relay_stopped, BOUND, "the relay stops")
