"""KyberCore on a real 3-node NATS cluster (JetStream clustered, loopback): its buckets are
kept in three copies, so losing the node a process is connected to loses neither the
registry nor the leases; a single server keeps one copy."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from pathlib import Path

import nats.errors
import pytest
from nats.aio.client import Client
from nats.js.api import ObjectStoreConfig

from kybercore.errors import BrokerUnavailable
from kybercore.registry.models import PrinterCreate
from kybercore.scale.broker import LocalServer, connect
from kybercore.scale.buckets import REPLICAS, object_store
from kybercore.scale.leases import SLOTS_BUCKET, Leases
from kybercore.scale.registry import BUCKET, KvRegistry
from kybercore.sim.stack import free_port
from tests.helpers import wait_for

SLOTS = 8
TTL = 3.0
AFTER_URL = "http://127.0.0.1:7102"
READY_WITHIN = 60.0
"""A cluster elects its JetStream leaders in seconds; a busy machine may take longer."""


@pytest.fixture
def nodes(tmp_path: Path) -> Iterator[list[LocalServer]]:
    """Three nats-servers routed to one another, JetStream clustered."""
    routes = [free_port() for _ in range(3)]
    started = []
    try:
        for i, port in enumerate(routes):
            others = ",".join(f"nats://127.0.0.1:{p}" for p in routes if p != port)
            node = LocalServer(
                tmp_path / f"n{i}", "--name", f"n{i}", "--cluster_name", "kc",
                "--cluster", f"nats://127.0.0.1:{port}", "--routes", others,
            )  # fmt: skip
            node.start()
            started.append(node)
        yield started
    finally:
        for node in started:
            node.close()


async def ready(nc: Client) -> bool:
    """JetStream answers (its meta leader is elected)."""
    try:
        await nc.jetstream().account_info()
    except (nats.errors.Error, TimeoutError):  # no meta leader to answer yet
        return False
    return True


async def test_losing_the_node_a_process_is_on_loses_no_printer_and_no_lease(
    nodes: list[LocalServer], tmp_path: Path
) -> None:
    url = ",".join(node.url for node in nodes)
    nc = await connect(url, "front")
    worker_nc = await connect(url, "worker")
    worker = Leases(worker_nc, "w1", url=url, slots=SLOTS, ttl=TTL, log_path=tmp_path / "w1.log")
    try:
        await wait_for(lambda: ready(nc), READY_WITHIN, "JetStream on the cluster")
        registry = KvRegistry()
        await registry.open(nc)
        await worker.start()
        js = nc.jetstream()
        for bucket in (BUCKET, SLOTS_BUCKET):
            assert (await js.stream_info(f"KV_{bucket}")).config.num_replicas == REPLICAS
        await registry.add(PrinterCreate(name="Before", moonraker_url="http://127.0.0.1:7101"))
        await wait_for(lambda: len(worker.owned()) == SLOTS, READY_WITHIN, "w1 owns every slot")

        assert nc.connected_url is not None
        lost = next(node for node in nodes if node.port == nc.connected_url.port)
        await asyncio.to_thread(lost.stop)

        async def added() -> bool:
            # What the error says to do: reload the list, and make the change again if it
            # is not there (an add that timed out may have been made).
            try:
                if "After" not in [p.name for p in await registry.printers()]:
                    await registry.add(PrinterCreate(name="After", moonraker_url=AFTER_URL))
            except BrokerUnavailable:
                return False
            return True

        await wait_for(added, READY_WITHIN, "the registry to take a change again")
        assert [p.name for p in await registry.printers()] == ["After", "Before"]
        # The leases too: the worker holds (or took back) every slot on the two nodes left.
        await wait_for(lambda: len(worker.owned()) == SLOTS, READY_WITHIN, "w1 owns every slot")
    finally:
        await worker.stop(release=False)
        await worker_nc.close()
        await nc.close()


async def test_a_single_server_keeps_one_copy(nats_server: LocalServer) -> None:
    nc = await connect(nats_server.url, "test")
    try:
        await KvRegistry().open(nc)  # creates its buckets
        assert (await nc.jetstream().stream_info(f"KV_{BUCKET}")).config.num_replicas == 1
    finally:
        await nc.close()


async def test_a_cluster_without_room_for_every_copy_says_so(
    nodes: list[LocalServer], monkeypatch: pytest.MonkeyPatch
) -> None:
    # One copy would stay on one server for good: losing it would stop the fleet.
    await asyncio.to_thread(nodes[2].stop)
    monkeypatch.setattr("kybercore.scale.buckets.PLACE_WITHIN", 1.0)
    nc = await connect(",".join(node.url for node in nodes[:2]), "front")
    try:
        await wait_for(lambda: ready(nc), READY_WITHIN, "JetStream on the cluster")
        with pytest.raises(BrokerUnavailable, match="needs at least 3 servers with JetStream"):
            await KvRegistry().open(nc)
    finally:
        await nc.close()


async def test_a_bucket_left_with_one_copy_on_a_cluster_is_pointed_out(
    nodes: list[LocalServer], caplog: pytest.LogCaptureFixture
) -> None:
    # Made before KyberCore replicated its buckets: used as it is, and said how to fix.
    nc = await connect(",".join(node.url for node in nodes), "front")
    try:
        await wait_for(lambda: ready(nc), READY_WITHIN, "JetStream on the cluster")
        await nc.jetstream().create_key_value(bucket=BUCKET, history=10, replicas=1)
        await KvRegistry().open(nc)
        assert "nats stream edit KV_kc_registry --replicas 3" in caplog.text
        assert "KV_kc_secrets" not in caplog.text  # created now, with 3 copies
        # An object store is opened for each upload: said once per connection, not each time.
        config = ObjectStoreConfig(bucket="kc_test_files")
        await nc.jetstream().create_object_store("kc_test_files", config)
        for _ in range(3):
            await object_store(nc, config)
        assert caplog.text.count("nats stream edit OBJ_kc_test_files --replicas 3") == 1
    finally:
        await nc.close()
