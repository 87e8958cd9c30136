"""An upload's way across a real nats-server, with a stand-in for the printer's service: the
file arrives whole and checked, every ending says what happened, and no object is left. A
command with the broker away is refused at once, as an upload is."""

from __future__ import annotations

import asyncio
import hashlib
import os
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, cast

import pytest
from nats.aio.client import Client
from nats.aio.msg import Msg

from kybercore.errors import (
    BrokerUnavailable,
    OutcomeUnknown,
    OwnerMoving,
    TransferFailed,
    UploadCorrupted,
)
from kybercore.fleet.actions import ActionOutcome
from kybercore.fleet.service import FleetService
from kybercore.scale import uploads as uploads_module
from kybercore.scale.broker import LocalServer, connect
from kybercore.scale.commands import CommandRunner, send_command
from kybercore.scale.uploads import BUCKET, UploadOrder, Uploads, send_upload
from kybercore.scale.wire import command_subject, decode_outcome
from tests.helpers import subscribed, wait_for
from tests.scale.at_once import at_once, cut_off
from tests.scale.objects import stored, stored_bytes

PRINTER = "p1"


@dataclass
class StandIn:
    """The owner's FleetService.upload, recording what it was given."""

    received: list[tuple[str, bytes, bool, bool]] = field(default_factory=list)
    hold: asyncio.Event | None = None

    async def upload(
        self,
        printer_id: str,
        filename: str,
        content: bytes | BinaryIO,
        *,
        start: bool = False,
        confirm: bool = False,
    ) -> ActionOutcome:
        assert not isinstance(content, bytes)  # a file, never the bytes in memory
        self.received.append((filename, content.read(), start, confirm))
        if self.hold is not None:
            await self.hold.wait()
        return ActionOutcome(printer_id, "upload", f"Uploaded {filename}.")


@dataclass
class Pair:
    front: Client
    worker: Client
    service: StandIn


@pytest.fixture
async def pair(nats_server: LocalServer) -> AsyncIterator[Pair]:
    """A front's connection, and a worker's owning PRINTER with the stand-in service."""
    front = await connect(nats_server.url, "front")
    worker = await connect(nats_server.url, "worker")
    service = StandIn()
    runner = CommandRunner(cast(FleetService, service), lambda _p: 1, uploads=Uploads(worker))
    await worker.subscribe(command_subject(PRINTER), cb=runner.on_message)
    # The front asks on a connection of its own: the server must hold the subscription
    # first, or it answers "no responders".
    await subscribed(worker)
    yield Pair(front, worker, service)
    await runner.stop()
    await front.close()
    await worker.close()


def gcode(size: int) -> bytes:
    lines, total, i = [b"; generated for a test\n", b"G28\n"], 0, 0
    while total < size:
        line = f"G1 X{i % 200} Y{(i * 7) % 200} ; move {i} {os.urandom(8).hex()}\n".encode()
        lines.append(line)
        total += len(line)
        i += 1
    return b"".join(lines)


async def test_a_file_larger_than_a_message_arrives_whole(pair: Pair, tmp_path: Path) -> None:
    data = gcode(3 * 1024 * 1024)  # NATS's max payload is 1 MB
    path = tmp_path / "big.gcode"
    path.write_bytes(data)
    with path.open("rb") as spooled:
        body = await send_upload(
            pair.front, PRINTER, "big.gcode", spooled, start=True, confirm=True, epoch=lambda: 1
        )
    outcome = decode_outcome(body)
    assert (outcome.printer_id, outcome.action, outcome.message) == (
        PRINTER,
        "upload",
        "Uploaded big.gcode.",
    )
    [(filename, received, start, confirm)] = pair.service.received
    assert (filename, start, confirm) == ("big.gcode", True, True)
    assert hashlib.sha256(received).digest() == hashlib.sha256(data).digest()
    assert await stored(pair.front) == []
    assert await stored_bytes(pair.front) < 4096  # the chunks purged, not only hidden


async def test_a_copy_that_differs_is_refused_and_nothing_uploaded(pair: Pair) -> None:
    name, size, sha256 = await Uploads(pair.front).put(b"G28\n", PRINTER)
    wrong = UploadOrder(name, size, hashlib.sha256(b"G29\n").hexdigest(), "a.gcode", start=True)
    with pytest.raises(UploadCorrupted, match="Nothing was uploaded or started"):
        await send_command(pair.front, PRINTER, "upload", wrong.as_args())
    short = UploadOrder(name, size + 1, sha256, "a.gcode")
    with pytest.raises(TransferFailed, match="no longer in the broker"):  # deleted above
        await send_command(pair.front, PRINTER, "upload", short.as_args())
    assert pair.service.received == []
    assert await stored(pair.front) == []


async def test_nobody_owning_the_printer_is_a_503_and_leaves_nothing(pair: Pair) -> None:
    with pytest.raises(OwnerMoving, match="Nothing was sent"):
        await send_upload(
            pair.front, "p2", "a.gcode", b"G28\n", start=False, confirm=False, epoch=lambda: 1
        )
    assert await stored(pair.front) == []


async def test_no_answer_in_time_says_to_look_at_the_file_list(
    pair: Pair, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(uploads_module, "answer_seconds", lambda _size: 0.5)
    pair.service.hold = asyncio.Event()
    try:
        with pytest.raises(OutcomeUnknown) as unknown:
            await send_upload(
                pair.front, PRINTER, "slow.gcode", b"G28\n", start=True, confirm=False,
                epoch=lambda: 1,
            )  # fmt: skip
    finally:
        pair.service.hold.set()
    message = unknown.value.message
    assert "took it but did not answer" in message  # the ack came at once
    assert "'slow.gcode' may or may not be on the printer (and printing)" in message
    assert "file list" in message
    assert await stored(pair.front) == []


async def test_the_broker_away_is_said_and_nothing_is_sent(
    pair: Pair, nats_server: LocalServer
) -> None:
    nats_server.stop()
    with pytest.raises(TransferFailed, match="NATS broker failed while taking the file"):
        await send_upload(
            pair.front, PRINTER, "a.gcode", b"G28\n", start=False, confirm=False, epoch=lambda: 1
        )
    assert pair.service.received == []


async def test_an_upload_while_the_broker_is_away_is_refused_at_once(
    pair: Pair, nats_server: LocalServer
) -> None:
    await cut_off(nats_server, pair.front, "front")
    with (
        at_once("upload refused"),
        pytest.raises(TransferFailed, match=r"taking the file \(ConnectionReconnectingError"),
    ):
        await send_upload(
            pair.front, PRINTER, "a.gcode", b"G28\n", start=False, confirm=False, epoch=lambda: 1
        )
    assert pair.service.received == []


async def test_a_worker_cut_off_from_the_broker_gives_up_an_upload_at_once(
    pair: Pair, nats_server: LocalServer
) -> None:
    order = UploadOrder(object="o1", size=4, sha256="0" * 64, filename="a.gcode")
    await cut_off(nats_server, pair.worker, "worker")
    with (
        at_once("upload given up"),
        pytest.raises(TransferFailed, match=r"handing the file to its worker \(ConnectionRe"),
    ):
        await Uploads(pair.worker).fetch(order, PRINTER)


async def test_a_command_while_the_broker_is_away_is_refused_at_once_and_never_sent_later(
    pair: Pair, nats_server: LocalServer
) -> None:
    arrived: list[bytes] = []

    async def sniff(msg: Msg) -> None:
        arrived.append(msg.data)

    await pair.worker.subscribe(command_subject(PRINTER), cb=sniff)
    await cut_off(nats_server, pair.front, "front")
    with (
        at_once("command refused"),
        pytest.raises(BrokerUnavailable, match=r"nothing was sent to the printer p1"),
    ):
        await send_command(pair.front, PRINTER, "emergency_stop", {})
    # nats-py would have held it and sent it once reconnected: nothing comes then.
    nats_server.start(port=nats_server.port)
    await wait_for(lambda: pair.front.is_connected and pair.worker.is_connected, 30, "reconnects")
    await subscribed(pair.front)
    await subscribed(pair.worker)
    assert arrived == []


async def test_the_bucket_expires_what_a_dead_process_left(nats_server: LocalServer) -> None:
    nc = await connect(nats_server.url, "front")
    try:
        await Uploads(nc).put(b"G28\n", PRINTER)
        status = await (await nc.jetstream().object_store(BUCKET)).status()
        assert status.ttl == uploads_module.TTL_SECONDS
    finally:
        await nc.close()
