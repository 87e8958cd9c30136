"""A printer's file on its way to a front's queue, across a real nats-server, with a
stand-in for the owner's Moonraker client: the file arrives whole and checked through
``kc_jobfiles``, a file the printer lacks is the printer's own error, and a broker that
refuses the file says so."""

from __future__ import annotations

import hashlib
import io
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from typing import Any, cast

import pytest
from nats.aio.client import Client
from nats.js.api import ObjectStoreConfig

from kybercore.errors import MoonrakerRpcError, TransferFailed
from kybercore.fleet.service import FleetService
from kybercore.scale.broker import LocalServer, connect
from kybercore.scale.commands import CommandRunner, send_command
from kybercore.scale.front import FrontFleet
from kybercore.scale.jobfiles import BUCKET, JobFileBucket
from kybercore.scale.queue import FrontPrinters
from kybercore.scale.wire import command_subject
from tests.helpers import subscribed
from tests.scale.at_once import at_once, cut_off
from tests.scale.test_upload_transfer import PRINTER, gcode


@dataclass
class StandIn:
    """The owner's FleetService, as far as FleetPrinters.download reaches: a client whose
    gcodes folder is ``files``."""

    files: dict[str, bytes] = field(default_factory=dict)

    def client(self, printer_id: str) -> StandIn:
        return self

    async def download(self, path: str, root: str = "gcodes") -> bytes:
        if path not in self.files:
            raise MoonrakerRpcError(404, f"File {path} does not exist", printer=PRINTER)
        return self.files[path]


@dataclass
class Front:
    """What FrontPrinters.download uses of a FrontFleet: its commands and its connection."""

    nc: Client

    async def command(self, printer_id: str, op: str, **args: Any) -> Any:
        return await send_command(self.nc, printer_id, op, args)


@pytest.fixture
async def pair(nats_server: LocalServer) -> AsyncIterator[tuple[FrontPrinters, StandIn]]:
    """A front's printers, and the stand-in printer of the worker owning PRINTER."""
    front = await connect(nats_server.url, "front")
    worker = await connect(nats_server.url, "worker")
    service = StandIn()
    runner = CommandRunner(
        cast(FleetService, service), lambda _p: 1, jobfiles=JobFileBucket(worker)
    )
    await worker.subscribe(command_subject(PRINTER), cb=runner.on_message)
    # The front asks on a connection of its own: the server must hold the subscription
    # first, or it answers "no responders".
    await subscribed(worker)
    yield FrontPrinters(cast(FrontFleet, Front(front))), service
    await runner.stop()
    await front.close()
    await worker.close()


async def test_a_file_larger_than_a_message_arrives_whole_and_stays_shared(
    pair: tuple[FrontPrinters, StandIn], nats_server: LocalServer
) -> None:
    printers, printer = pair
    data = gcode(3 * 1024 * 1024)  # NATS's max payload is 1 MB
    printer.files["big.gcode"] = data
    assert await printers.download(PRINTER, "big.gcode") == data
    # Stored under its sha256, as the queue's own files: the queue finds it shared already.
    nc = await connect(nats_server.url, "test")
    try:
        bucket = await nc.jetstream().object_store(BUCKET)
        names = [info.name for info in await bucket.list(ignore_deletes=True)]
        assert names == [hashlib.sha256(data).hexdigest()]
    finally:
        await nc.close()


async def test_a_file_the_printer_lacks_is_the_printers_404(
    pair: tuple[FrontPrinters, StandIn],
) -> None:
    printers, _ = pair
    with pytest.raises(MoonrakerRpcError, match="does not exist") as caught:
        await printers.download(PRINTER, "nope.gcode")
    assert caught.value.rpc_code == 404


async def test_a_broker_that_refuses_the_file_is_a_transfer_failure(
    pair: tuple[FrontPrinters, StandIn], nats_server: LocalServer
) -> None:
    printers, printer = pair
    nc = await connect(nats_server.url, "test")
    try:  # a bucket too small for the file (the worker opens it, never re-creates it)
        await nc.jetstream().create_object_store(BUCKET, ObjectStoreConfig(max_bytes=64 * 1024))
    finally:
        await nc.close()
    printer.files["big.gcode"] = gcode(256 * 1024)
    with pytest.raises(TransferFailed, match=r"did not take the job file 'big\.gcode'") as caught:
        await printers.download(PRINTER, "big.gcode")
    assert caught.value.code == "transfer_failed"


@pytest.fixture
async def front_cut_off(nats_server: LocalServer) -> AsyncIterator[Client]:
    """A front's connection that has seen the broker go."""
    nc = await connect(nats_server.url, "front")
    try:
        await cut_off(nats_server, nc, "front")
        yield nc
    finally:
        await nc.close()


async def test_a_job_file_while_the_broker_is_away_is_refused_at_once(
    front_cut_off: Client,
) -> None:
    with (
        at_once("job file refused"),
        pytest.raises(TransferFailed, match=r"'a\.gcode' \(ConnectionReconnectingError\)"),
    ):
        await JobFileBucket(front_cut_off).share("0" * 64, io.BytesIO(b"G28\n"), "a.gcode")


async def test_a_front_cut_off_from_the_broker_gives_up_fetching_a_job_file_at_once(
    front_cut_off: Client,
) -> None:
    with (
        at_once("job file fetch given up"),
        pytest.raises(TransferFailed, match=r"fetched from the NATS broker \(ConnectionRe"),
    ):
        await JobFileBucket(front_cut_off).fetch("0" * 64, io.BytesIO())
